"""Twin critics Q_1, Q_2(s, c, a) as one batched network (the soft actor-critic's clipped double-Q)."""

from __future__ import annotations

from collections.abc import Sequence

import torch
from torch import nn

from digail.nets.mlp import mlp


class TwinQ(nn.Module):
    """Two ReLU MLPs on [normalised obs, one-hot code, action], stored as stacked weights so that both run in one
    batched matmul per layer (`torch.baddbmm`): half the operations of two separate nets, the same maths.

    `weights[i]` is (2, in_i, out_i) and `biases[i]` (2, 1, out_i); each critic starts as an `mlp` would
    (orthogonal weights, zero biases).
    """

    def __init__(self, obs_dim: int, codes: int, act_dim: int, hidden: Sequence[int] = (256, 256)) -> None:
        super().__init__()
        in_dim = obs_dim + codes + act_dim
        nets = [mlp(in_dim, 1, hidden) for _ in range(2)]
        layers = [[m for m in net if isinstance(m, nn.Linear)] for net in nets]
        self.weights = nn.ParameterList(
            nn.Parameter(torch.stack([ls[i].weight.detach().t() for ls in layers]).contiguous())
            for i in range(len(layers[0])))
        self.biases = nn.ParameterList(
            nn.Parameter(torch.stack([ls[i].bias.detach()[None] for ls in layers]).contiguous())
            for i in range(len(layers[0])))
        self.code_inputs = slice(obs_dim, obs_dim + codes)
        """the input rows that carry the one-hot code"""

    def zero_code_weights(self) -> None:
        """Zero both critics' first-layer weights on the code inputs: Q starts the same under every code."""
        with torch.no_grad():
            self.weights[0][:, self.code_inputs] = 0.0

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        """Both critics' values (2, B) for ready inputs x (B, in) = [obs_n, one-hot code, action]."""
        h = x.expand(2, *x.shape)
        n = len(self.weights)
        for i, (w, b) in enumerate(zip(self.weights, self.biases, strict=True)):
            h = torch.baddbmm(b, h, w)
            if i < n - 1:
                h = torch.relu(h)
        return h.squeeze(-1)
