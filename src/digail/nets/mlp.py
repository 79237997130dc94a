"""Multi-layer perceptrons (paper appendix: 2 hidden layers of 64 ReLU units)."""

from __future__ import annotations

from collections.abc import Sequence

import torch
import torch.nn.functional as F
from torch import nn


def mlp(in_dim: int, out_dim: int, hidden: Sequence[int] = (64, 64), out_gain: float = 1.0) -> nn.Sequential:
    """A ReLU MLP with orthogonal initialisation; `out_gain` scales the last layer (small for policy heads)."""
    layers: list[nn.Module] = []
    dims = [in_dim, *hidden]
    for a, b in zip(dims[:-1], dims[1:], strict=True):
        layers += [_init(nn.Linear(a, b), 2**0.5), nn.ReLU()]
    layers.append(_init(nn.Linear(dims[-1], out_dim), out_gain))
    return nn.Sequential(*layers)


def _init(layer: nn.Linear, gain: float) -> nn.Linear:
    nn.init.orthogonal_(layer.weight, gain)
    nn.init.zeros_(layer.bias)
    return layer


def zero_last_inputs(seq: nn.Sequential, n: int) -> None:
    """Zero the first layer's weights on the last `n` inputs of an `mlp`: its output stops depending on them."""
    first = seq[0]
    assert isinstance(first, nn.Linear)
    with torch.no_grad():
        first.weight[:, first.in_features - n:] = 0.0


def one_hot(codes: torch.Tensor, k: int) -> torch.Tensor:
    """Float one-hot of integer `codes`; a code of -1 (the start input) gives the zero vector."""
    out = torch.zeros(*codes.shape, k, device=codes.device)
    valid = codes >= 0
    out[valid] = torch.nn.functional.one_hot(codes[valid], k).float()
    return out


Layers = list[tuple[torch.Tensor, torch.Tensor]]


def linear_layers(seq: nn.Sequential) -> Layers:
    """The (weight, bias) pairs of an `mlp`, for `mlp_apply`."""
    return [(m.weight, m.bias) for m in seq if isinstance(m, nn.Linear)]


def mlp_apply(layers: Layers, x: torch.Tensor) -> torch.Tensor:
    """`seq(x)` of the `mlp` whose `linear_layers` these are: the same operations (linear, ReLU, ..., linear), so
    the same numbers and gradients, without the module calls, which cost more than the 2x64 layers' arithmetic in
    the many-step VAE and polish loops."""
    for w, b in layers[:-1]:
        x = torch.relu(F.linear(x, w, b))
    w, b = layers[-1]
    return F.linear(x, w, b)
