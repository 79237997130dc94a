"""PPO (Schulman et al., 2017) with GAE: the advantage estimator and a pure update step."""

from __future__ import annotations

from collections.abc import Callable
from typing import Any, cast

import numpy as np
import torch

from digail.algos.aux_losses import AnchorLoss
from digail.algos.batch import PPOBatch
from digail.algos.ppo_grad import PPOGrad
from digail.config import PPOConfig
from digail.nets.critic import ValueNet
from digail.nets.policy import SubtaskPolicy


@torch.no_grad()
def compute_gae(rews: torch.Tensor, values: torch.Tensor, terminated: torch.Tensor, truncated: torch.Tensor,
                final_values: torch.Tensor, last_values: torch.Tensor, gamma: float, lam: float
                ) -> tuple[torch.Tensor, torch.Tensor]:
    """Generalised advantage estimation over a (T, N) rollout; returns (advantages, value targets).

    `terminated[t]` / `truncated[t]` say the episode ended after step t. A terminal state is worth 0. A time-limit
    truncation is *not* terminal: the value of the true final observation, `final_values[t]`, is bootstrapped
    (the env has already been reset, so `values[t + 1]` belongs to a new episode and is cut off in both cases).
    `last_values` is V of the observation after the last step, used where the rollout stops mid-episode.
    """
    # A NumPy loop: T small steps cost far less outside torch's per-op dispatch (~10x here).
    r, v = rews.cpu().numpy(), values.cpu().numpy()
    not_done = 1.0 - (terminated | truncated).cpu().numpy().astype(np.float32)
    boot = final_values.cpu().numpy() * truncated.cpu().numpy()
    nxt = np.concatenate([v[1:], last_values.cpu().numpy()[None]], 0)
    deltas = r + gamma * (nxt * not_done + boot) - v
    adv_np = np.zeros_like(r)
    gae = np.zeros_like(r[0])
    for t in range(len(r) - 1, -1, -1):
        gae = deltas[t] + gamma * lam * not_done[t] * gae
        adv_np[t] = gae
    adv = torch.from_numpy(adv_np).to(rews.device)
    return adv, adv + values


def minibatch_loss(policy: SubtaskPolicy, value: ValueNet, x_pi: torch.Tensor, x_v: torch.Tensor,
                   acts: torch.Tensor, logp_old: torch.Tensor, adv: torch.Tensor, returns: torch.Tensor,
                   clip: float, vf_coef: float, ent_coef: float) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """PPO's loss on one minibatch of net inputs (`policy.inputs(...)` for pi, [obs, code] for V).

    Returns the loss to minimise, the detached (policy, value, entropy) losses and the detached log-ratios
    log pi(a | s, c) - log pi_old(a | s, c) (for the KL and clip-fraction diagnostics).
    """
    v_loss = value_loss(value, x_v, returns)
    logp, entropy = policy.log_prob_entropy_of(x_pi, acts)
    log_ratio = logp - logp_old
    ratio = log_ratio.exp()
    pg_loss = -torch.min(ratio * adv, ratio.clamp(1 - clip, 1 + clip) * adv).mean()
    entropy = entropy.mean()
    loss = pg_loss + vf_coef * v_loss - ent_coef * entropy
    return loss, torch.stack([pg_loss, v_loss, entropy]).detach(), log_ratio.detach()


def value_loss(value: ValueNet, x_v: torch.Tensor, returns: torch.Tensor) -> torch.Tensor:
    """The critic's loss alone (the warm-up before the policy trains)."""
    return 0.5 * (value.net(x_v).squeeze(-1) - returns).pow(2).mean()


_compiled: dict[Callable[..., Any], Callable[..., Any]] = {}
_compile_failed = False


def maybe_compiled(fn: Callable[..., Any], compile_: bool) -> Callable[..., Any]:
    """`fn`, or its `torch.compile`d form (made once per process) when asked and compiling has not failed here.

    The compiled form falls back to `fn` for good, with one warning, the first time compiling fails (no C++
    compiler, an unsupported device).
    """
    if not compile_ or _compile_failed:
        return fn
    if fn not in _compiled:
        compiled = torch.compile(fn, dynamic=False)

        def call(*args: Any) -> Any:
            global _compile_failed
            if _compile_failed:
                return fn(*args)
            try:
                return compiled(*args)
            except Exception as exc:  # torch.compile raises backend errors of many types
                import warnings

                _compile_failed = True
                warnings.warn(f"torch.compile failed ({type(exc).__name__}: {str(exc)[:200]}); continuing "
                              "without compiling (--train.ppo.no-compile skips the attempt).", stacklevel=2)
                return fn(*args)

        _compiled[fn] = call
    return _compiled[fn]


def reset_compiled() -> None:
    """Forget the compiled forms and a past compile failure: the next `maybe_compiled` tries `torch.compile` anew
    (e.g. after the compiler was installed or replaced within one process)."""
    global _compile_failed
    _compiled.clear()
    _compile_failed = False


class LeanStep:
    """Gradient-norm clipping and Adam in a handful of foreach calls per step.

    `nn.utils.clip_grad_norm_` and `torch.optim.Adam.step` spend most of their time for 2x64 nets in Python
    bookkeeping (device grouping, state lookups, per-tensor norms): ~200 us per step against ~50 us for the
    same kernels called directly (measured). This calls them directly on the optimiser's own state, so its
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
        if not isinstance(opt, torch.optim.Adam) or not hasattr(torch, "_fused_adam_"):
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
        grads = [p.grad for p in self.params if p.grad is not None]
        if grads and self.max_norm is not None:
            total = torch.linalg.vector_norm(torch.stack(torch._foreach_norm(grads)))
            torch._foreach_mul_(grads, (self.max_norm / (total + 1e-6)).clamp_(max=1.0))
        if len(grads) < len(self.params) or (self.groups is None and not self._lean_groups()):
            self.optimizer.step()  # creates the state on the first step; skips parameters without gradients
            return
        assert self.groups is not None
        for g, params, exp_avgs, exp_avg_sqs, steps in self.groups:
            beta1, beta2 = g["betas"]
            torch._foreach_add_(steps, 1)
            torch._fused_adam_(params, [cast(torch.Tensor, p.grad) for p in params], exp_avgs, exp_avg_sqs, [], steps,
                               amsgrad=False, lr=g["lr"], beta1=beta1, beta2=beta2, weight_decay=0.0,
                               eps=g["eps"], maximize=False, grad_scale=None, found_inf=None)


def ppo_update(policy: SubtaskPolicy, value: ValueNet, optimizer: torch.optim.Optimizer, batch: PPOBatch,
               cfg: PPOConfig, generator: torch.Generator,
               aux_losses: dict[str, tuple[Callable[[], torch.Tensor], float]] | None = None,
               train_policy: bool = True, hand_grad: bool = True) -> dict[str, float]:
    """Clipped-surrogate PPO epochs over `batch`; returns mean losses and diagnostics.

    Pure apart from the parameters and optimiser it is handed: no hidden state, no env access. `aux_losses` maps
    names to (loss function, weight): each with a positive weight is evaluated once per minibatch (e.g. the BC
    term on fresh expert samples) and added to the policy's loss; its mean comes back under its name. With
    `train_policy=False` only the value loss is minimised (critic warm-up).

    A minibatch step is a few dozen small torch ops, so their count is the cost: the net inputs are built once
    per update, each epoch gathers its permutation once (minibatches are then contiguous views) and normalises
    all its minibatches' advantages in one op, the diagnostics stay tensors until the epoch ends, and clipping
    and Adam run as direct foreach calls (`LeanStep`). `cfg.compile` also compiles the loss and its backward.
    Where it applies (a Gaussian policy and plain `mlp` nets, no aux term but the anchor, `cfg.compile` off,
    `hand_grad` on) the loss and its gradient come from one scripted function instead (`ppo_grad.PPOGrad`):
    a Circle-World update runs about 2.3x faster (measured), with the same numbers to float rounding.
    """
    n = len(batch)
    mb = min(cfg.minibatch_size, n)
    n_mb = n // mb  # full minibatches only; an epoch's remainder rows sit that epoch out
    with torch.no_grad():
        x_pi = policy.inputs(batch.obs, batch.codes)
        x_v = x_pi if policy.decoder_obs is None else torch.cat([batch.obs, batch.codes], -1)
    loss_fn, v_loss_fn = maybe_compiled(minibatch_loss, cfg.compile), maybe_compiled(value_loss, cfg.compile)
    step = LeanStep(optimizer, cfg.max_grad_norm)
    aux = {k: fw for k, fw in (aux_losses or {}).items() if fw[1] > 0} if train_policy else {}
    sums = dict.fromkeys(("policy", "value", "entropy", "approx_kl", "clip_frac", *(aux_losses or {})), 0.0)
    updates = 0
    grad_fn = PPOGrad(policy, value) if hand_grad and train_policy and not cfg.compile else None
    # the hand-written gradient covers the anchor term alone among the aux terms; its frozen targets come once per
    # update (the values per minibatch were the same, to float rounding), its rows are drawn per minibatch as before.
    # That needs an anchor that cannot move during the update: no parameter of it trains
    anchor_name, (anchor_fn, anchor_coef) = next(iter(aux.items()), ("", (None, 0.0)))
    own_anchor = (isinstance(anchor_fn, AnchorLoss) and anchor_fn.pi is policy and anchor_fn.batch is batch
                  and not any(p.requires_grad for p in anchor_fn.anchor.parameters()))
    if grad_fn is not None and grad_fn.applies and (not aux or (len(aux) == 1 and own_anchor)):
        no_rows = x_pi[:0]  # pi's inputs and targets for no anchor rows (no anchor term)
        # each step sets every covered gradient; one clear here leaves any other parameter's at None, not stale
        optimizer.zero_grad(set_to_none=True)
        with torch.no_grad():
            targets = (anchor_fn.anchor.net(anchor_fn.anchor.inputs(batch.obs, batch.codes))
                       if isinstance(anchor_fn, AnchorLoss) else no_rows)
    else:
        grad_fn = None
    for _ in range(cfg.epochs):
        perm = torch.randperm(n, generator=generator)[: n_mb * mb]
        e_pi, e_acts, e_logp, e_returns = (t[perm] for t in (x_pi, batch.acts, batch.logp, batch.returns))
        e_v = e_pi if x_v is x_pi else x_v[perm]
        e_adv = batch.adv[perm].view(n_mb, mb)
        if cfg.norm_adv and mb > 1:
            e_adv = (e_adv - e_adv.mean(1, keepdim=True)) / (e_adv.std(1, keepdim=True) + 1e-8)
        log_ratios, losses = [], []
        aux_parts: dict[str, list[torch.Tensor]] = {k: [] for k in aux} if grad_fn is None else {}
        for i in range(n_mb):
            rows = slice(i * mb, (i + 1) * mb)
            if grad_fn is not None:
                idx = anchor_fn.rows() if isinstance(anchor_fn, AnchorLoss) else None
                parts, log_ratio = grad_fn(e_pi[rows], e_v[rows], e_acts[rows], e_logp[rows], e_adv[i],
                                           e_returns[rows], no_rows if idx is None else x_pi[idx],
                                           no_rows if idx is None else targets[idx], cfg.clip, cfg.vf_coef,
                                           cfg.ent_coef, anchor_coef)
                log_ratios.append(log_ratio)
                losses.append(parts)  # [policy, value, entropy, anchor]
                step()
                continue
            if train_policy:
                loss, parts, log_ratio = loss_fn(policy, value, e_pi[rows], e_v[rows], e_acts[rows],
                                                 e_logp[rows], e_adv[i], e_returns[rows], cfg.clip, cfg.vf_coef,
                                                 cfg.ent_coef)
                for name, (fn, weight) in aux.items():
                    part = fn()
                    loss = loss + weight * part
                    aux_parts[name].append(part.detach())
                log_ratios.append(log_ratio)
                losses.append(parts)
            else:
                loss = v_loss_fn(value, e_v[rows], e_returns[rows])
                losses.append(loss.detach())
            optimizer.zero_grad(set_to_none=True)
            loss.backward()
            step()
        # the epoch's diagnostics in a few ops: minibatches have equal sizes, so means of means are overall means
        kl = 0.0
        if train_policy:
            pg, vl, ent, *anchor_sum = torch.stack(losses).sum(0).tolist()
            if anchor_sum and aux:  # the hand-written gradient's anchor term
                sums[anchor_name] += anchor_sum[0]
            lr_all = torch.stack(log_ratios)
            ratio_all = lr_all.exp()
            kl = float(((ratio_all - 1) - lr_all).mean())
            sums["approx_kl"] += kl * n_mb
            sums["clip_frac"] += float(((ratio_all - 1).abs() > cfg.clip).float().mean()) * n_mb
            sums["policy"] += pg
            sums["entropy"] += ent
            for name, parts_ in aux_parts.items():
                sums[name] += float(torch.stack(parts_).sum())
        else:
            vl = float(torch.stack(losses).sum())
        sums["value"] += vl
        updates += n_mb
        if cfg.target_kl is not None and train_policy and kl > cfg.target_kl:
            break
    return {k: v / max(updates, 1) for k, v in sums.items()}
