"""The optimiser step of every trainer: gradient-norm clipping and fused Adam as direct foreach calls."""

from __future__ import annotations

from typing import Any, cast

import torch

from digail.algos.fast import enabled
from digail.algos.fast.ops import adam_step, clip_grad_norm


class LeanStep:
    """Gradient-norm clipping and Adam in a handful of foreach calls per step.

    `nn.utils.clip_grad_norm_` and `torch.optim.Adam.step` spend most of their time for 2x64 nets in Python
    bookkeeping (device grouping, state lookups, per-tensor norms): ~200 us per step against ~50 us for the
    same kernels called directly. This calls them directly on the optimiser's own state, so its
    `state_dict` stays what torch saves and loads; anything it does not cover (not fused Adam, AMSGrad, weight
    decay, state not yet created) takes the optimiser's own `step`.
    """

    def __init__(self, optimizer: torch.optim.Optimizer, max_norm: float | None) -> None:
        self.optimizer, self.max_norm = optimizer, max_norm
        self.params = [p for g in optimizer.param_groups for p in g["params"]]
        self.groups: list[tuple[dict[str, Any], list[torch.Tensor], list[torch.Tensor], list[torch.Tensor],
                                list[torch.Tensor]]] | None = None

    def _lean_groups(self) -> bool:
        opt = self.optimizer
        if not isinstance(opt, torch.optim.Adam):
            return False
        groups = []
        for g in opt.param_groups:
            if not g.get("fused") or g["amsgrad"] or g["weight_decay"] or g["maximize"] or g["capturable"]:
                return False
            states = [opt.state.get(p, {}) for p in g["params"]]
            if not all("exp_avg" in st for st in states):
                return False
            groups.append((g, list(g["params"]), [st["exp_avg"] for st in states],
                           [st["exp_avg_sq"] for st in states], [st["step"] for st in states]))
        self.groups = groups
        return True

    def __call__(self) -> None:
        if not enabled():  # the reference: torch's own clipping and optimiser step (the same numbers)
            if self.max_norm is not None:
                torch.nn.utils.clip_grad_norm_(self.params, self.max_norm, foreach=True)
            self.optimizer.step()
            return
        grads = [p.grad for p in self.params if p.grad is not None]
        if grads and self.max_norm is not None:
            clip_grad_norm(grads, self.max_norm)
        if len(grads) < len(self.params) or (self.groups is None and not self._lean_groups()):
            self.optimizer.step()  # creates the state on the first step; skips parameters without gradients
            return
        assert self.groups is not None
        for g, params, exp_avgs, exp_avg_sqs, steps in self.groups:
            beta1, beta2 = g["betas"]
            adam_step(params, [cast(torch.Tensor, p.grad) for p in params], exp_avgs, exp_avg_sqs, steps, g["lr"],
                      beta1, beta2, g["eps"])


class FusedAdamState:
    """The state of a plain fused `torch.optim.Adam` (one group: no AMSGrad, weight decay, maximize or capturable)
    as the lists `digail.algos.fast.sac_grad.fused_adam` takes (for `ops.adam_step`), for scripted updates that
    step the optimiser themselves. The optimiser keeps its state (its `state_dict` is what torch saves and loads).

    `lists()` is None until torch's own first `step` has created the state (or for an optimiser this does not
    cover); the lists are rebuilt when the optimiser loads a state dict (which replaces its state tensors).
    """

    def __init__(self, optimizer: torch.optim.Optimizer, params: list[torch.Tensor]) -> None:
        self.optimizer, self.params = optimizer, params
        self._state_of: object = None
        self._lists: list[list[torch.Tensor]] | None = None

    def lists(self) -> tuple[list[list[torch.Tensor]], list[float]] | None:
        """([exp_avgs, exp_avg_sqs, steps] in `params`' order, [lr, beta1, beta2, eps]), or None."""
        opt = self.optimizer
        if not enabled():
            return None
        if opt.state is not self._state_of or self._lists is None:
            self._lists = self._build()
            self._state_of = opt.state
        if self._lists is None:
            return None
        g = opt.param_groups[0]
        beta1, beta2 = g["betas"]
        return self._lists, [float(g["lr"]), float(beta1), float(beta2), float(g["eps"])]

    def _build(self) -> list[list[torch.Tensor]] | None:
        opt = self.optimizer
        if not isinstance(opt, torch.optim.Adam) or len(opt.param_groups) != 1:
            return None
        g = opt.param_groups[0]
        if (not g.get("fused") or g["amsgrad"] or g["weight_decay"] or g["maximize"] or g["capturable"]
                or isinstance(g["lr"], torch.Tensor) or {id(p) for p in g["params"]} != {id(p) for p in self.params}):
            return None
        states = [opt.state.get(p, {}) for p in self.params]
        if not all("exp_avg" in st for st in states):
            return None
        return [[st["exp_avg"] for st in states], [st["exp_avg_sq"] for st in states], [st["step"] for st in states]]
