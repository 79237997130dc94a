"""PPO (Schulman et al., 2017) with GAE: the advantage estimator and a pure update step."""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import numpy as np
import torch

from digail.algos import fast
from digail.algos.batch import PPOBatch
from digail.algos.fast.ppo_grad import PPOGrad
from digail.algos.optim import clipped_step
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


HAND_GRAD_MAX_ROWS = 256
"""the largest minibatch PPO's hand-written gradient runs on: at 128 rows (Circle-World) a step is dispatch-bound
and the gradient makes a whole iteration 1.7x faster than the compiled or eager loss; at 512 rows (Hopper) the
arithmetic dominates and it gains under 1.1x, less than it costs to keep a second gradient beside autograd's"""


def ppo_update(policy: SubtaskPolicy, value: ValueNet, optimizer: torch.optim.Optimizer, batch: PPOBatch,
               cfg: PPOConfig, generator: torch.Generator,
               aux_losses: dict[str, tuple[Callable[[], torch.Tensor], float]] | None = None,
               train_policy: bool = True) -> dict[str, float]:
    """Clipped-surrogate PPO epochs over `batch`; returns mean losses and diagnostics.

    Pure apart from the parameters and optimiser it is handed: no hidden state, no env access. `aux_losses` maps
    names to (loss function, weight): each with a positive weight is evaluated once per minibatch (e.g. the BC
    term on fresh expert samples) and added to the policy's loss; its mean comes back under its name. With
    `train_policy=False` only the value loss is minimised (critic warm-up).

    A minibatch step is a few dozen small torch ops, so their count is the cost: the net inputs are built once
    per update, each epoch gathers its permutation once (minibatches are then contiguous views) and normalises
    all its minibatches' advantages in one op, and the diagnostics stay tensors until the epoch ends.
    `cfg.compile` compiles the loss and its backward.
    On the fast path (`digail.algos.fast`), where it applies (a Gaussian policy and plain `mlp` nets, no aux term
    but the anchor, `cfg.compile` off, minibatches of at most `HAND_GRAD_MAX_ROWS` rows) the loss and its
    gradient come from one scripted function instead (`ppo_grad.PPOGrad`), with the same numbers to float
    rounding.
    """
    n = len(batch)
    mb = min(cfg.minibatch_size, n)
    n_mb = n // mb  # full minibatches only; an epoch's remainder rows sit that epoch out
    with torch.no_grad():
        x_pi = policy.inputs(batch.obs, batch.codes)
        x_v = x_pi if policy.decoder_obs is None else torch.cat([batch.obs, batch.codes], -1)
    loss_fn, v_loss_fn = maybe_compiled(minibatch_loss, cfg.compile), maybe_compiled(value_loss, cfg.compile)
    aux = {k: fw for k, fw in (aux_losses or {}).items() if fw[1] > 0} if train_policy else {}
    sums = dict.fromkeys(("policy", "value", "entropy", "approx_kl", "clip_frac", *(aux_losses or {})), 0.0)
    updates = 0
    hand = fast.enabled() and train_policy and not cfg.compile and mb <= HAND_GRAD_MAX_ROWS
    grad_fn = PPOGrad(policy, value) if hand else None
    # the hand-written gradient computes an aux term itself only where the term says how (`hand_grad_terms`, the
    # anchor's): its frozen targets once per update, its rows drawn per minibatch as the term would draw them
    anchor_name, (anchor_fn, anchor_coef) = next(iter(aux.items()), ("", (None, 0.0)))
    no_rows = x_pi[:0]  # pi's inputs and targets for no anchor rows (no anchor term)
    draw_rows, targets = None, no_rows
    if grad_fn is not None and grad_fn.applies and len(aux) <= 1:
        terms_of = getattr(anchor_fn, "hand_grad_terms", None)
        terms = terms_of(policy, batch) if terms_of is not None else None
        if aux and terms is None:
            grad_fn = None
        else:
            # each step sets every covered gradient; one clear here leaves any other parameter's at None, not stale
            optimizer.zero_grad(set_to_none=True)
            if terms is not None:
                draw_rows, targets = terms
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
                idx = draw_rows() if draw_rows is not None else None
                parts, log_ratio = grad_fn(e_pi[rows], e_v[rows], e_acts[rows], e_logp[rows], e_adv[i],
                                           e_returns[rows], no_rows if idx is None else x_pi[idx],
                                           no_rows if idx is None else targets[idx], cfg.clip, cfg.vf_coef,
                                           cfg.ent_coef, anchor_coef)
                log_ratios.append(log_ratio)
                losses.append(parts)  # [policy, value, entropy, anchor]
                clipped_step(optimizer, cfg.max_grad_norm)
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
            clipped_step(optimizer, cfg.max_grad_norm)
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
