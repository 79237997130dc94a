"""Inference-only snapshots of the networks for the rollout loop.

A rollout step runs q, pi and V on a handful of observations, where module dispatch, `torch.cat`, one-hot
matmuls and Distribution objects cost more than the arithmetic. A snapshot copies the weights once per rollout
(they do not change during one) into raw tensors: the code input becomes a row lookup added to the first layer's
bias, and pi and V share their matmuls through block-diagonal weights. Results equal the modules' up to float
rounding (tests/test_fast.py).
"""

from __future__ import annotations

import math

import torch
from torch import nn

from digail.nets.critic import ValueNet
from digail.nets.policy import SubtaskPolicy

LOG_2PI = math.log(2 * math.pi)


def _linears(seq: nn.Sequential) -> list[nn.Linear]:
    return [m for m in seq if isinstance(m, nn.Linear)]


class CodeMLP:
    """Snapshot of `mlp(obs_dim + K, out)` taking (obs_n, integer codes); code -1 is the zero (start) input."""

    def __init__(self, seqs: list[nn.Sequential], obs_dim: int,
                 obs_slices: list[tuple[int, int] | None] | None = None) -> None:
        layers = [_linears(s) for s in seqs]
        slices = obs_slices or [None] * len(seqs)
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
            self.w_obs = w_first[:obs_dim].contiguous()
            codes_rows = w_first[obs_dim:] + b_first  # row k: code k's contribution plus the bias
            self.code_table = torch.cat([codes_rows, b_first[None]], 0).contiguous()  # index -1: start input
            self.rest = []
            for depth in range(1, len(layers[0])):
                w = torch.block_diag(*[ls[depth].weight.t() for ls in layers]).contiguous()
                b = torch.cat([ls[depth].bias for ls in layers], 0)
                self.rest.append((w, b))

    def __call__(self, obs_n: torch.Tensor, codes: torch.Tensor) -> torch.Tensor:
        h = torch.mm(obs_n, self.w_obs).add_(self.code_table[codes]).relu_()
        last = len(self.rest) - 1
        for i, (w, b) in enumerate(self.rest):
            h = torch.addmm(b, h, w)
            if i < last:
                h.relu_()
        return h


class ActorCritic:
    """pi and V together: `sample(obs_n, codes)` -> actions, log-probabilities and values."""

    def __init__(self, pi: SubtaskPolicy, value: ValueNet, obs_dim: int) -> None:
        self.net = CodeMLP([pi.net, value.net], obs_dim, [getattr(pi, "obs_slice", None), None])
        self.discrete = pi.action.discrete
        self.act_dim = pi.action.dim
        if not self.discrete:
            with torch.no_grad():
                self.log_std = pi.log_std.detach().clamp(-5.0, 2.0).clone()
                self.std = self.log_std.exp()
                self.logp_const = float(-self.log_std.sum() - 0.5 * self.act_dim * LOG_2PI)

    def sample(self, obs_n: torch.Tensor, codes: torch.Tensor, generator: torch.Generator | None = None
               ) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        out = self(obs_n, codes)
        head, value = out[:, : self.act_dim], out[:, self.act_dim]
        if self.discrete:
            logp_all = torch.log_softmax(head, -1)
            gumbel = -torch.log(-torch.log(torch.rand(head.shape, generator=generator).clamp_(1e-20, 1.0)))
            acts = (logp_all + gumbel).argmax(-1)
            return acts, logp_all.gather(-1, acts[:, None]).squeeze(-1), value
        z = torch.randn(head.shape, generator=generator)
        acts = head + self.std * z
        return acts, self.logp_const - 0.5 * z.pow(2).sum(-1), value

    def value(self, obs_n: torch.Tensor, codes: torch.Tensor) -> torch.Tensor:
        return self(obs_n, codes)[:, self.act_dim]

    def __call__(self, obs_n: torch.Tensor, codes: torch.Tensor) -> torch.Tensor:
        return self.net(obs_n, codes)
