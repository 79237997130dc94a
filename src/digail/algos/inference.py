"""The networks as the rollouts call them: NumPy in, NumPy out, one row per env.

`actor_critic` and `code_net` return the fast path's float32 NumPy snapshots (`digail.algos.fast.inference`)
unless `digail.algos.fast` is switched to the reference, where they return `ModuleActorCritic` and `ModuleCodeNet`:
the same interface on the modules' own torch forward passes (the reference the snapshots are tested against,
tests/test_fast_path.py).
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Protocol, cast

import numpy as np
import torch
from torch.distributions import Categorical

from digail.algos import fast
from digail.nets.critic import ValueNet
from digail.nets.policy import SubtaskPolicy
from digail.nets.vae import MacroPolicy


class RolloutActorCritic(Protocol):
    """What `digail.algos.rollout.collect_rollout` calls pi and V through."""

    discrete: bool
    act_dim: int

    def sample_noise(self, rng: np.random.Generator, shape: tuple[int, ...]) -> np.ndarray: ...

    def sample(self, obs_n: np.ndarray, codes: np.ndarray, noise: np.ndarray
               ) -> tuple[np.ndarray, np.ndarray, np.ndarray]: ...

    def value(self, obs_n: np.ndarray, codes: np.ndarray) -> np.ndarray: ...


CodeNet = Callable[[np.ndarray, np.ndarray], np.ndarray]
"""(obs_n (N, D), integer previous codes (N,), -1 the start input) -> q's logits (N, K)"""


def _code_rows(codes: int, device: torch.device) -> torch.Tensor:
    """One-hot rows for codes 0 .. K - 1 and a zero row last, so that code -1 (the start input) picks zeros."""
    return torch.cat([torch.eye(codes, device=device), torch.zeros(1, codes, device=device)])


class ModuleActorCritic:
    """pi and V through their modules: `sample(obs_n, codes, noise)` -> actions, log-probabilities and values, with
    the noise of `sample_noise` (the interface of `digail.algos.fast.inference.ActorCritic`)."""

    def __init__(self, pi: SubtaskPolicy, value: ValueNet) -> None:
        self.pi, self.value_net = pi, value
        self.discrete = pi.action.discrete
        self.act_dim = pi.action.dim
        self.device = next(pi.parameters()).device
        self.rows = _code_rows(pi.codes, self.device)

    def sample_noise(self, rng: np.random.Generator, shape: tuple[int, ...]) -> np.ndarray:
        """The randomness `sample` needs for `shape` (e.g. (T, N)) steps: standard normals or Gumbels."""
        if self.discrete:
            return rng.gumbel(size=(*shape, self.act_dim)).astype(np.float32)
        return rng.standard_normal((*shape, self.act_dim), dtype=np.float32)

    @torch.no_grad()
    def sample(self, obs_n: np.ndarray, codes: np.ndarray, noise: np.ndarray
               ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Actions from pi(. | s, c) given `noise` (continuous: mean + std * noise; discrete: Gumbel-max over the
        logits), their log-probabilities under pi's distribution, and V(s, c)."""
        obs, code_1h = self._inputs(obs_n, codes)
        dist = self.pi.dist(obs, code_1h)
        z = torch.as_tensor(noise, device=self.device)
        # Categorical's `logits` are its normalised log-probabilities: Gumbel-max over them samples pi
        acts = (cast(Categorical, dist).logits + z).argmax(-1) if self.discrete else dist.mean + dist.stddev * z
        return (acts.cpu().numpy(), dist.log_prob(acts).float().cpu().numpy(),
                self.value_net(obs, code_1h).float().cpu().numpy())

    @torch.no_grad()
    def value(self, obs_n: np.ndarray, codes: np.ndarray) -> np.ndarray:
        return self.value_net(*self._inputs(obs_n, codes)).float().cpu().numpy()

    def _inputs(self, obs_n: np.ndarray, codes: np.ndarray) -> tuple[torch.Tensor, torch.Tensor]:
        obs = torch.as_tensor(np.asarray(obs_n, np.float32), device=self.device)
        return obs, self.rows[torch.as_tensor(codes, device=self.device)]


class ModuleCodeNet:
    """q's logits through its module for (obs_n, integer previous codes; -1 the start input), as NumPy (the
    interface of `digail.algos.fast.inference.CodeMLP` on q)."""

    def __init__(self, q: MacroPolicy) -> None:
        self.q = q
        self.device = next(q.parameters()).device
        self.rows = _code_rows(q.codes, self.device)

    @torch.no_grad()
    def __call__(self, obs_n: np.ndarray, codes: np.ndarray) -> np.ndarray:
        obs = torch.as_tensor(np.asarray(obs_n, np.float32), device=self.device)
        return self.q(obs, self.rows[torch.as_tensor(codes, device=self.device)]).float().cpu().numpy()


def actor_critic(pi: SubtaskPolicy, value: ValueNet, obs_dim: int) -> RolloutActorCritic:
    """pi and V for a rollout (their weights do not change during one): the NumPy snapshot on the fast path."""
    if fast.enabled():
        from digail.algos.fast.inference import ActorCritic

        return ActorCritic(pi, value, obs_dim)
    return ModuleActorCritic(pi, value)


def code_net(q: MacroPolicy, obs_dim: int) -> CodeNet:
    """q's logits for a rollout (q frozen during one): the NumPy snapshot on the fast path."""
    if fast.enabled():
        from digail.algos.fast.inference import CodeMLP

        return CodeMLP([q.net], obs_dim)
    return ModuleCodeNet(q)
