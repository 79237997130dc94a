"""The optimiser every trainer uses (VAE, polish, PPO, discriminator), its step, and the stop on a non-finite loss."""

from __future__ import annotations

import math
from typing import Any

import torch

from digail.errors import TrainingError


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


def check_finite(values: dict[str, float], iteration: int) -> None:
    """Stop the run with one sentence when a loss is not finite (the last good checkpoint stays)."""
    bad = [k for k, v in values.items() if not math.isfinite(v)]
    if bad:
        raise TrainingError(f"non-finite loss ({', '.join(bad)}) at iteration {iteration + 1}; the last good "
                            "checkpoint is kept - lower the learning rate or check the demonstrations.")
