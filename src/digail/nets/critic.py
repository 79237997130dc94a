"""Value function V(s, c) and discriminator D(s, a)."""

from __future__ import annotations

from collections.abc import Sequence

import torch
from torch import nn

from digail.nets.mlp import mlp, zero_last_inputs


class ValueNet(nn.Module):
    """V(s_t, c_t) on normalised observations and one-hot codes (the code changes what the policy will do)."""

    def __init__(self, obs_dim: int, codes: int, hidden: Sequence[int] = (64, 64)) -> None:
        super().__init__()
        self.net = mlp(obs_dim + codes, 1, hidden)
        self.codes = codes

    def zero_code_weights(self) -> None:
        """Zero the first layer's weights on the code inputs: V starts the same under every code."""
        zero_last_inputs(self.net, self.codes)

    def forward(self, obs_n: torch.Tensor, code_1h: torch.Tensor) -> torch.Tensor:
        return self.net(torch.cat([obs_n, code_1h], -1)).squeeze(-1)


class Discriminator(nn.Module):
    """D_omega(s, a) returning `logits_expert_is_high`: sigmoid(logit) = D = P(expert | s, a).

    Trained with binary cross-entropy, expert pairs labelled 1 and agent pairs 0. Actions enter as one-hots for
    discrete spaces and as the executed (clipped / canonical) action for continuous ones.
    """

    def __init__(self, obs_dim: int, act_dim: int, hidden: Sequence[int] = (64, 64)) -> None:
        super().__init__()
        self.net = mlp(obs_dim + act_dim, 1, hidden)

    def forward(self, obs_n: torch.Tensor, act_in: torch.Tensor) -> torch.Tensor:
        return self.net(torch.cat([obs_n, act_in], -1)).squeeze(-1)


def generator_reward(logits_expert_is_high: torch.Tensor, kind: str = "positive") -> torch.Tensor:
    """Reward for the policy from D's logits l, with D = sigmoid(l) the probability of 'expert'.

    - positive: -log(1 - D) = softplus(l) >= 0. A survival bonus: right for envs that terminate on failure
      (Hopper, Walker), since each step alive earns reward.
    - negative: log D = -softplus(-l) <= 0. A step cost: pushes towards ending episodes early.
    - logit: log D - log(1 - D) = l, the AIRL-style reward, unbiased about episode length.
    The paper writes the GAN objective with the policy minimising E[log D(s, a)] where D scores the *agent*;
    with our expert-is-high D the policy maximises any of the above.
    """
    if kind == "positive":
        return nn.functional.softplus(logits_expert_is_high)
    if kind == "negative":
        return -nn.functional.softplus(-logits_expert_is_high)
    if kind == "logit":
        return logits_expert_is_high
    raise ValueError(f"unknown reward kind {kind!r}")
