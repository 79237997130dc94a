"""The optimiser every trainer uses (VAE, polish, PPO, discriminator) and its step."""

from __future__ import annotations

from typing import Any

import torch


def adam(params: list[Any], lr: float, eps: float = 1e-8) -> torch.optim.Adam:
    """Adam with the fused kernel where this torch build has it (about 1.6x faster PPO epochs for 2x64 nets on
    CPU, measured), else the default implementation; the maths is the same. `params` may be parameter groups."""
    try:
        return torch.optim.Adam(params, lr=lr, eps=eps, fused=True)
    except (RuntimeError, TypeError):
        return torch.optim.Adam(params, lr=lr, eps=eps)


def clipped_step(optimizer: torch.optim.Optimizer, max_norm: float | None) -> None:
    """The optimiser's step after clipping its parameters' gradients to a joint 2-norm of `max_norm` (None: no
    clipping)."""
    if max_norm is not None:
        params = [p for g in optimizer.param_groups for p in g["params"]]
        torch.nn.utils.clip_grad_norm_(params, max_norm, foreach=True)
    optimizer.step()
