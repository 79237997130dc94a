"""Value function V(s, c) (the discriminator D(s, a) is a reward's: `digail.algos.rewards.discriminator`)."""

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
