"""Inference-only NumPy snapshots of the networks for the rollout loop.

A rollout step runs q, pi and V on a handful of observations (one row per env), where each torch op costs more
dispatch time than its arithmetic. A snapshot copies the weights once per rollout (they do not change during one)
into float32 NumPy arrays: the code input becomes a row lookup added to the first layer's bias, and pi and V share
their matmuls through block-diagonal weights. Noise comes in from outside (`sample_noise`, one draw per rollout)
so that the step itself is a few small array operations. Results equal the modules' up to float rounding
(tests/test_fast.py).
"""

from __future__ import annotations

import numpy as np
import torch
from torch import nn

from digail.nets.critic import ValueNet
from digail.nets.policy import LOG_2PI, LOG_STD_BOUNDS, SubtaskPolicy


def _linears(seq: nn.Sequential) -> list[nn.Linear]:
    return [m for m in seq if isinstance(m, nn.Linear)]


def _np(t: torch.Tensor) -> np.ndarray:
    return np.ascontiguousarray(t.detach().cpu().numpy(), dtype=np.float32)


def log_softmax(logits: np.ndarray) -> np.ndarray:
    """Row-wise log-softmax of a (B, K) array."""
    z = logits - logits.max(-1, keepdims=True)
    return z - np.log(np.exp(z).sum(-1, keepdims=True))


def _relu_tail(h: np.ndarray, rest: list[tuple[np.ndarray, np.ndarray]]) -> np.ndarray:
    """The rest of a ReLU MLP after its first layer's pre-activation `h` (modified in place)."""
    np.maximum(h, 0.0, out=h)
    for w, b in rest[:-1]:
        h = h @ w
        h += b
        np.maximum(h, 0.0, out=h)
    w, b = rest[-1]
    out = h @ w
    out += b
    return out


class CodeMLP:
    """Snapshot of `mlp(obs_dim + K, out)` taking (obs_n, integer codes); code -1 is the zero (start) input.

    Several nets on the same input (`seqs`, e.g. pi and V) run as one: their outputs are concatenated.
    """

    def __init__(self, seqs: list[nn.Sequential], obs_dim: int,
                 input_slices: list[tuple[int, int] | None] | None = None) -> None:
        layers = [_linears(s) for s in seqs]
        slices = input_slices or [None] * len(seqs)
        with torch.no_grad():
            first = [ls[0] for ls in layers]
            # a net that sees only a slice of the observation gets zero weights for the rest
            w_full = []
            for f, sl in zip(first, slices, strict=True):
                if sl is None:
                    w_full.append(f.weight)
                else:
                    w = f.weight.new_zeros(f.weight.shape[0], obs_dim + f.weight.shape[1] - (sl[1] - sl[0]))
                    w[:, sl[0]:sl[1]] = f.weight[:, : sl[1] - sl[0]]
                    w[:, obs_dim:] = f.weight[:, sl[1] - sl[0]:]
                    w_full.append(w)
            w_first = torch.cat(w_full, 0).t()  # (obs_dim + K, H_total)
            b_first = torch.cat([f.bias for f in first], 0)
            self.w_obs = _np(w_first[:obs_dim])
            codes_rows = w_first[obs_dim:] + b_first  # row k: code k's contribution plus the bias
            self.code_table = _np(torch.cat([codes_rows, b_first[None]], 0))  # index -1: the start input
            self.rest = [(_np(torch.block_diag(*[ls[depth].weight.t() for ls in layers])),
                          _np(torch.cat([ls[depth].bias for ls in layers], 0)))
                         for depth in range(1, len(layers[0]))]

    def __call__(self, obs_n: np.ndarray, codes: np.ndarray) -> np.ndarray:
        h = obs_n @ self.w_obs
        h += self.code_table.take(codes, 0)
        return _relu_tail(h, self.rest)


class ActorCritic:
    """pi and V together: `sample(obs_n, codes, noise)` -> actions, log-probabilities and values (NumPy)."""

    def __init__(self, pi: SubtaskPolicy, value: ValueNet, obs_dim: int) -> None:
        self.net = CodeMLP([pi.net, value.net], obs_dim, [pi.decoder_obs, None])
        self.discrete = pi.action.discrete
        self.act_dim = pi.action.dim
        if not self.discrete:
            with torch.no_grad():
                log_std = pi.log_std.detach().clamp(*LOG_STD_BOUNDS)
                self.std = _np(log_std.exp())
                self.logp_const = np.float32(-log_std.sum() - 0.5 * self.act_dim * LOG_2PI)

    def sample_noise(self, rng: np.random.Generator, shape: tuple[int, ...]) -> np.ndarray:
        """The randomness `sample` needs for `shape` (e.g. (T, N)) steps: standard normals or Gumbels."""
        if self.discrete:
            return rng.gumbel(size=(*shape, self.act_dim)).astype(np.float32)
        return rng.standard_normal((*shape, self.act_dim), dtype=np.float32)

    def sample(self, obs_n: np.ndarray, codes: np.ndarray, noise: np.ndarray
               ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Actions from pi(. | s, c) given `noise` (one row of `sample_noise`), their log-probabilities, V(s, c).

        Continuous: a = mean + std * z, so log pi(a) = const - |z|^2 / 2. Discrete: Gumbel-max over the logits.
        """
        out = self(obs_n, codes)
        head, value = out[:, : self.act_dim], out[:, self.act_dim]
        if self.discrete:
            logp_all = log_softmax(head)
            acts = (logp_all + noise).argmax(-1)
            return acts, np.take_along_axis(logp_all, acts[:, None], -1)[:, 0], value
        acts = head + self.std * noise
        return acts, self.logp_const - 0.5 * (noise * noise).sum(-1), value

    def value(self, obs_n: np.ndarray, codes: np.ndarray) -> np.ndarray:
        return self(obs_n, codes)[:, self.act_dim]

    def __call__(self, obs_n: np.ndarray, codes: np.ndarray) -> np.ndarray:
        return self.net(obs_n, codes)
