"""Every private torch op the fast path calls, in one module, checked once against the torch it was tested with.

The hand-written gradients and optimiser steps call ops that torch does not promise to keep: the ReLU, softmax and
log-softmax backward kernels, the fused Adam kernel and the foreach list ops. `TESTED` is the range of torch
versions that pyproject.toml pins and the tests run on. On import this module checks the running torch against it
and looks every op up; where either fails, `problem` says why, the fast path turns itself off
(`digail.algos.fast.enabled`), one warning says so, and training runs the reference path: autograd and
`torch.optim`, the same numbers to float rounding, slower.

The functions below are the only callers of those ops; they are plain enough for TorchScript, so the scripted
gradients call them directly.
"""

from __future__ import annotations

import warnings

import torch
from torch import Tensor

TESTED = ((2, 3), (2, 15))
"""torch versions the fast path is tested on: from the first up to, not including, the second (pyproject's pin)"""


def _problem() -> str | None:
    """Why the fast path cannot run on this torch (None: it can)."""
    try:
        major, minor = (int(part) for part in torch.__version__.split("+")[0].split(".")[:2])
    except ValueError:
        return f"torch {torch.__version__} has a version string digail does not read"
    if not TESTED[0] <= (major, minor) < TESTED[1]:
        return (f"torch {torch.__version__} is outside the versions it is tested on "
                f"({'.'.join(map(str, TESTED[0]))} up to {'.'.join(map(str, TESTED[1]))})")
    missing = [name for name in ("_fused_adam_", "_foreach_add_", "_foreach_lerp_",
                                 "_softmax_backward_data", "_log_softmax_backward_data") if not hasattr(torch, name)]
    if not hasattr(torch.ops.aten, "threshold_backward"):
        missing.append("ops.aten.threshold_backward")
    if missing:
        return f"torch {torch.__version__} lacks {', '.join('torch.' + m for m in missing)}"
    return None


problem = _problem()
"""why the fast path is off on this torch (None: it can run)"""
if problem is not None:
    warnings.warn(f"digail's fast path is off: {problem}; training runs the reference path (the same numbers, "
                  "slower).", RuntimeWarning, stacklevel=2)


def relu_backward(g: Tensor, out: Tensor) -> Tensor:
    """The gradient through a ReLU whose output was `out`: `g` where `out` > 0, else 0."""
    return torch.ops.aten.threshold_backward(g, out, 0.0)


def softmax_backward(g: Tensor, y: Tensor) -> Tensor:
    """The gradient through a softmax over the last dimension whose output was `y`."""
    return torch._softmax_backward_data(g, y, -1, g.dtype)


def log_softmax_backward(g: Tensor, out: Tensor) -> Tensor:
    """The gradient through a log-softmax over the last dimension whose output was `out`."""
    return torch._log_softmax_backward_data(g, out, -1, out.dtype)


def adam_step(params: list[Tensor], grads: list[Tensor], exp_avgs: list[Tensor], exp_avg_sqs: list[Tensor],
              steps: list[Tensor], lr: float, beta1: float, beta2: float, eps: float) -> None:
    """`torch.optim.Adam(fused=True).step` on its own state (no AMSGrad, weight decay or maximize): the same two
    kernel calls, so the same bits. The one Adam of the fast path."""
    torch._foreach_add_(steps, 1)
    torch._fused_adam_(params, grads, exp_avgs, exp_avg_sqs, [], steps, amsgrad=False, lr=lr, beta1=beta1,
                       beta2=beta2, weight_decay=0.0, eps=eps, maximize=False, grad_scale=None, found_inf=None)


def polyak(targets: list[Tensor], sources: list[Tensor], tau: float) -> None:
    """targets <- targets + tau (sources - targets), in place."""
    torch._foreach_lerp_(targets, sources, tau)
