"""The optimisers' state as the scripted SAC and D steps take it (`FusedAdamState`)."""

from __future__ import annotations

import torch


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
