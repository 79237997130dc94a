"""Sub-task policy pi(a | s, c): Gaussian (state-independent log-std) or categorical head on an MLP."""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import gymnasium as gym
import numpy as np
import torch
from torch import nn
from torch.distributions import Categorical, Distribution, Independent, Normal

from digail.nets.mlp import mlp, zero_last_inputs

LOG_STD_BOUNDS = (-5.0, 2.0)
"""the Gaussian policy's log-std is clamped to this range wherever it is used (std 0.0067 .. 7.4); the
TorchScript gradients (`digail.algos.fast.ppo_grad`, `vae_grad`, `polish_grad`) cannot read module constants and
repeat it, which `tests/test_fast.py` checks"""


@dataclass(frozen=True)
class ActionSpec:
    """What the policy head needs to know about an action space."""

    discrete: bool
    """categorical (True) or Gaussian (False)"""
    dim: int
    """number of actions (discrete) or action dimensions (continuous)"""

    @staticmethod
    def from_space(space: gym.Space) -> ActionSpec:
        if isinstance(space, gym.spaces.Discrete):
            return ActionSpec(True, int(space.n))
        if isinstance(space, gym.spaces.Box) and len(space.shape) == 1:
            return ActionSpec(False, int(space.shape[0]))
        raise ValueError(f"unsupported action space {space}; digail handles Discrete and 1-D Box actions")

    @staticmethod
    def from_actions(acts: np.ndarray, n_discrete: int | None = None) -> ActionSpec:
        """Infer from demonstration actions: integer actions are discrete with `n_discrete` (or max + 1) values."""
        acts = np.asarray(acts)
        if np.issubdtype(acts.dtype, np.integer):
            return ActionSpec(True, int(n_discrete if n_discrete is not None else acts.max() + 1))
        return ActionSpec(False, int(acts.reshape(len(acts), -1).shape[1]))


LOG_2PI = math.log(2 * math.pi)


class SubtaskPolicy(nn.Module):
    """pi_theta(a_t | s_t, c_t) on normalised observations and one-hot codes (paper section 3.1, decoder)."""

    def __init__(self, obs_dim: int, codes: int, action: ActionSpec, hidden: Sequence[int] = (64, 64),
                 init_log_std: float = -0.5, decoder_obs: tuple[int, int] | None = None) -> None:
        super().__init__()
        self.codes, self.action = codes, action
        self.decoder_obs = decoder_obs
        """the observation features [start, stop) this policy sees (None: all); e.g. Four Rooms' agent position,
        leaving the goal to the macro-policy so that the code has to say where to go"""
        seen = obs_dim if decoder_obs is None else decoder_obs[1] - decoder_obs[0]
        self.net = mlp(seen + codes, action.dim, hidden, out_gain=0.01)
        if not action.discrete:
            self.log_std = nn.Parameter(torch.full((action.dim,), init_log_std))

    def zero_code_weights(self) -> None:
        """Zero the first layer's weights on the code inputs: the policy acts the same under every code."""
        zero_last_inputs(self.net, self.codes)

    def inputs(self, obs_n: torch.Tensor, code_1h: torch.Tensor) -> torch.Tensor:
        """The net's input for normalised observations and codes (the seen slice, then the code)."""
        if self.decoder_obs is not None:
            obs_n = obs_n[..., self.decoder_obs[0]:self.decoder_obs[1]]
        return torch.cat([obs_n, code_1h], -1)

    def dist(self, obs_n: torch.Tensor, code_1h: torch.Tensor) -> Distribution:
        """Action distribution for normalised observations and (one-hot or relaxed) codes."""
        out = self.net(self.inputs(obs_n, code_1h))
        if self.action.discrete:
            return Categorical(logits=out, validate_args=False)  # argument checks cost more than the net here
        std = self.log_std.clamp(*LOG_STD_BOUNDS).exp().expand_as(out)
        return Independent(Normal(out, std, validate_args=False), 1, validate_args=False)

    def log_prob_entropy(self, obs_n: torch.Tensor, code_1h: torch.Tensor, acts: torch.Tensor
                         ) -> tuple[torch.Tensor, torch.Tensor]:
        """log pi(a | s, c) and the entropy, computed in closed form (the PPO hot path; no Distribution objects)."""
        logp, entropy = self.log_prob_entropy_of(self.inputs(obs_n, code_1h), acts)
        return logp, entropy.expand(len(logp))

    def log_prob_entropy_of(self, inputs: torch.Tensor, acts: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """`log_prob_entropy` from ready net inputs (`inputs(...)`); the Gaussian's entropy comes back as one
        scalar, since it does not depend on the state (the PPO update's form: fewest ops per minibatch)."""
        return self.head_log_prob_entropy(self.net(inputs), acts)

    def head_log_prob_entropy(self, out: torch.Tensor, acts: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """`log_prob_entropy_of` from the net's output (for callers that run the net themselves: `mlp_apply`)."""
        if self.action.discrete:
            logp_all = torch.log_softmax(out, -1)
            return logp_all.gather(-1, acts.long()[..., None]).squeeze(-1), -(logp_all.exp() * logp_all).sum(-1)
        log_std = self.log_std.clamp(*LOG_STD_BOUNDS)
        z = (acts - out) * torch.exp(-log_std)
        log_std_sum = log_std.sum()
        logp = -0.5 * z.pow(2).sum(-1) - log_std_sum - 0.5 * self.action.dim * LOG_2PI
        return logp, log_std_sum + 0.5 * self.action.dim * (1.0 + LOG_2PI)

    def mode(self, obs_n: torch.Tensor, code_1h: torch.Tensor) -> torch.Tensor:
        """Most likely action (argmax or mean)."""
        out = self.net(self.inputs(obs_n, code_1h))
        return out.argmax(-1) if self.action.discrete else out
