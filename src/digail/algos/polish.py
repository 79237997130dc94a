"""The polish after VAE pre-training: the codes fixed to q's own causal segmentation of the demonstrations, pi fitted
by maximum likelihood and q by cross-entropy on jittered states (`VAEConfig.polish_steps`, `q_noise`, `q_anticipate`).
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np
import torch
import torch.nn.functional as F
from torch import Tensor

from digail.algos import fast
from digail.algos.fast.scripting import scripted
from digail.algos.optim import adam
from digail.config import VAEConfig
from digail.data.trajectory import Trajectory
from digail.errors import UserError
from digail.nets.mlp import linear_layers
from digail.nets.vae import HierarchicalPolicy
from digail.utils import progress_bar


def polish(model: HierarchicalPolicy, trajs: Sequence[Trajectory], cfg: VAEConfig, *, seed: int = 0,
           progress: bool = True, minibatch: int = 256) -> HierarchicalPolicy:
    """Sharpen pi and q on the VAE's own causal segmentation of `trajs` (`VAEConfig.polish_steps`); in place.

    The VAE's joint objective stops at a loose decoder (its few thousand steps share the codes' noise), and q
    only ever saw the expert's exact states. With the codes fixed to `segment_many`'s causal decoding, pi is
    fitted by maximum likelihood and q by cross-entropy on states jittered by `cfg.q_noise` feature stds.
    """
    from digail.algos.decode import segment_many

    return fit_to_codes(model, trajs, segment_many(model, trajs), cfg.polish_steps, cfg.polish_lr,
                        q_noise=cfg.q_noise, q_anticipate=cfg.q_anticipate, seed=seed, progress=progress,
                        minibatch=minibatch)


def fit_to_codes(model: HierarchicalPolicy, trajs: Sequence[Trajectory], codes_per_demo: Sequence[np.ndarray],
                 steps: int, lr: float, *, q_noise: float = 0.0, q_anticipate: int = 0, seed: int = 0,
                 progress: bool = True, minibatch: int = 256, desc: str = "polish") -> HierarchicalPolicy:
    """Fit pi by maximum likelihood of a_t given (s_t, c_t) and q by cross-entropy of c_t given (s_t, c_{t-1})
    to the given codes (one (T_i,) array per demonstration), `steps` Adam steps at rate `lr` cosine-decayed to
    0; in place. What `polish` does with q's own segmentation, and `VAEConfig.init` with a first one."""
    dev = next(model.parameters()).device
    obs = torch.as_tensor(np.concatenate([np.asarray(t.obs[:-1], np.float32).reshape(len(t.acts), -1)
                                          for t in trajs]), device=dev)
    acts = torch.as_tensor(np.concatenate([np.asarray(t.acts) for t in trajs]), device=dev)
    if not model.action.discrete:
        acts = acts.float().reshape(len(acts), -1)
    codes = torch.as_tensor(np.concatenate(codes_per_demo), device=dev)
    # q's targets anticipate each switch; its previous-code inputs stay the segmentation's, so the switching
    # state itself (previous code still the old one) keeps its target too
    q_codes = torch.as_tensor(np.concatenate([anticipate_switches(c, q_anticipate) for c in codes_per_demo]),
                              device=dev)
    start = model.codes  # index of the zero row: c_{-1}
    prevs = torch.as_tensor(np.concatenate([np.r_[start, c[:-1]] for c in codes_per_demo]), device=dev)
    table = torch.cat([torch.eye(model.codes, device=dev), torch.zeros(1, model.codes, device=dev)])
    with torch.no_grad():
        obs_n = model.normalizer(obs)
        # pi's input rows are built once here instead of per minibatch (concatenation is exact: same numbers)
        pi_in = model.pi.inputs(obs_n, table[codes])
    prev_1h = table[prevs]
    q_in, obs_dim = torch.cat([obs_n, prev_1h], -1), obs_n.shape[1]
    model.train()
    params = [*model.pi.parameters(), *model.q.parameters()]
    opt = adam(params, lr)
    group = opt.param_groups[0]
    lrs = cosine_lrs(lr, steps)
    # the fast path: the loss and its gradient as one scripted function (`fast.polish_grad.step_grads`: autograd's
    # own backward kernels, so the same numbers)
    hand = fast.enabled()
    if hand:
        from digail.algos.fast.polish_grad import step_grads as hand_grads

        pi_layers, q_layers = linear_layers(model.pi.net), linear_layers(model.q.net)
        pi_w, pi_b = [w for w, _ in pi_layers], [b for _, b in pi_layers]
        q_w, q_b = [w for w, _ in q_layers], [b for _, b in q_layers]
        discrete = model.action.discrete
        log_std = model.q.net[0].weight if discrete else model.pi.log_std  # unused when discrete
        targets = [*pi_w, *pi_b, *([] if discrete else [log_std]), *q_w, *q_b]
        step_grads = scripted(hand_grads)
    gen = torch.Generator(device=dev).manual_seed(seed + 7919)
    bar = progress_bar(steps, progress, desc=desc, unit="step")
    for step in range(steps):
        group["lr"] = lrs[step]
        idx = torch.randint(0, len(obs_n), (minibatch,), generator=gen, device=dev)
        q_x = q_in.index_select(0, idx)  # [obs_n, prev_1h] rows: MacroPolicy.forward's input
        if q_noise > 0:
            q_x[:, :obs_dim] += q_noise * torch.randn((minibatch, obs_dim), generator=gen, device=dev)
        if hand:
            with torch.no_grad():
                grads, loss = step_grads(pi_in.index_select(0, idx), acts.index_select(0, idx), q_x,
                                         q_codes.index_select(0, idx), pi_w, pi_b, log_std, q_w, q_b, discrete)
            for p, g in zip(targets, grads, strict=True):
                p.grad = g
        else:
            loss = polish_loss(model, pi_in.index_select(0, idx), acts.index_select(0, idx), q_x,
                               q_codes.index_select(0, idx))
            for p in params:
                p.grad = None
            loss.backward()
        opt.step()
        if bar is not None and step % 200 == 0:
            bar.set_postfix(loss=f"{loss.item():.3f}", refresh=False)
            bar.update(min(200, steps - step))
    if bar is not None:
        bar.close()
    if not all(torch.isfinite(p).all() for p in params):
        raise UserError("the VAE polish diverged (non-finite weights); lower --vae.polish-lr or set "
                        "--vae.polish-steps 0.")
    return model.eval()


def polish_loss(model: HierarchicalPolicy, pi_x: Tensor, acts: Tensor, q_x: Tensor, q_codes: Tensor) -> Tensor:
    """The polish's loss on one minibatch, -mean log pi(a | s, c) + CE(q(s~, c_prev), c), through the modules
    (the reference for `digail.algos.fast.polish_grad.step_grads`). `pi_x` are pi's net inputs
    (`SubtaskPolicy.inputs`), `q_x` q's ([obs_n, previous one-hot])."""
    log_pi, _ = model.pi.log_prob_entropy_of(pi_x, acts)
    return -log_pi.mean() + F.cross_entropy(model.q.net(q_x), q_codes)


def anticipate_switches(codes: np.ndarray, steps: int) -> np.ndarray:
    """`codes` with every switch moved up to `steps` steps earlier (never before the previous switch).

    The polish takes q's targets from this sequence (q's previous-code inputs and pi keep the original): the
    macro-policy then switches anywhere on the last `steps` states before the expert's switch as well as on it.
    """
    out = np.array(codes, copy=True)
    if steps <= 0:
        return out
    switches = np.flatnonzero(np.diff(codes)) + 1
    for i, t in enumerate(switches):
        first = max(t - steps, switches[i - 1] + 1 if i else 1)
        out[first:t] = codes[t]
    return out


def cosine_lrs(base: float, steps: int) -> list[float]:
    """The learning rate of each of `steps` optimiser steps under cosine annealing from `base` to 0 over `steps`.

    The same floats as stepping `torch.optim.lr_scheduler.CosineAnnealingLR(opt, steps)` after each step (its
    recursive form, tested against it), without the scheduler's per-step Python work, which cost about a tenth of
    a polish step.
    """
    lrs = [base]
    for e in range(1, steps):
        lrs.append((1 + math.cos(math.pi * e / steps)) / (1 + math.cos(math.pi * (e - 1) / steps)) * lrs[-1])
    return lrs[:steps]
