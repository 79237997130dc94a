"""VAE pre-training of the hierarchical policy (paper section 3.1 and appendix).

The encoder is the macro-policy q(c_t | s_t, c_{t-1}), the decoder the sub-task policy pi(a_t | s_t, c_t), and the
prior a learned table p(c_t | c_{t-1}). Per demonstration, relaxed one-hot codes c~_t are drawn one step at a
time with the Gumbel-softmax trick from q(. | s_t, c~_{t-1}) (c~_{-1} is the zero start vector), each sample fed
as the next step's previous code, and the loss is

    L = - sum_t log pi(a_t | s_t, c~_t)
        + beta * sum_t KL(q(. | s_t, c~_{t-1}) || p(. | c~_{t-1}))
        + lambda_s * sum_{t>=1} [1 - c~_{t-1} . c~_t / max(|c~_{t-1}|, |c~_t|)]
        - eta * sum_t H(q(. | s_t, c~_{t-1}))

The third term is the smoothing penalty of the paper's appendix (Circle-World): zero while the code stays put, one
per switch between one-hots. The KL is the exact categorical KL (no sampling). Every sum is divided by the number
of steps in the batch, so the logged numbers are per-step averages; Adam does not care about the overall scale.

Choices beyond the paper, each measured on the shipped Circle-World demonstrations (100 episodes, K = 2, 1000
epochs, the paper's temperature schedule; "collapse" = one code for whole episodes, accuracy 0.5):

- Gradient through the previous code (`VAEConfig.bptt`, default off). The samples are always drawn sequentially;
  by default the gradient stops at q's previous-code input (q's logits at every step are recomputed in one batched
  pass from the sampled previous codes). Exact backpropagation through the chain (`bptt=True`, hand-written in
  `_GumbelChain`) was slower (about 90 s instead of 60 s) and less reliable: 0 of 5 runs ended segmented (most
  left the plateau, then collapsed), against 2 of 3 with the same settings and the gradient stopped.
- Warm-up (`warmup_epochs`) of the KL and smoothing weights from 0, and a small entropy bonus eta on q
  (`entropy_weight`). Without them about half the runs collapsed: q sits on the learned prior while the decoder
  ignores the codes, or, with a warm-up alone, q turns into a saturated constant just as the switch forms. With a
  warm-up of 200 epochs and eta = 0.03 (the circle-world preset), 6 of 6 seeds found the clockwise /
  counter-clockwise split; eta = 0.1 kept q too undecided for the decoder to use the codes.
- The circle-world preset's smoothing weight is 0.1: at 1.0 the penalty on undecided (soft) codes pushed q onto a
  single code (2 of 2 runs).

Speed: only the sampling chain is sequential. The first layer of q is split into its state and code parts; the
state part for every step, the Gumbel noise and the output bias are computed before the time loop, so each step
costs one small matrix product per layer and a softmax. The decoder, the KL, the smoothing and entropy terms are
evaluated on the whole (batch, time) block at once. Demonstrations of different lengths are padded and masked.
"""

from __future__ import annotations

import csv
import math
import time
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import torch
import torch.nn.functional as F
from torch import nn

from digail.algos.optim import adam
from digail.config import VAEConfig
from digail.data.trajectory import Trajectory
from digail.errors import UserError
from digail.nets.policy import ActionSpec
from digail.nets.vae import HierarchicalPolicy, MacroPolicy
from digail.utils import resolve_device, seed_everything

LOSS_KEYS = ("losses/total", "losses/recon", "losses/kl", "losses/smooth")


# ------------------------------------------------------------------------------------------ data layout
@dataclass(frozen=True)
class DemoBatch:
    """Demonstrations padded to a common length (batch-major).

    Padded steps hold zeros and are excluded from every loss by `mask`.
    """

    obs_n: torch.Tensor
    """(B, T, obs_dim) normalised observations s_0 .. s_{T-1} (the final observation is not needed)"""
    acts: torch.Tensor
    """(B, T, act_dim) float actions, or (B, T) int64 action indices"""
    mask: torch.Tensor
    """(B, T) float, 1 on real steps"""

    def __getitem__(self, idx: torch.Tensor) -> DemoBatch:
        """The demonstrations `idx`, cropped to the longest of them."""
        mask = self.mask[idx]
        t_max = int(mask.sum(1).max().item())
        return DemoBatch(self.obs_n[idx, :t_max], self.acts[idx, :t_max], mask[:, :t_max])


def check_demos(trajs: Sequence[Trajectory], action_spec: ActionSpec | None = None) -> tuple[int, ActionSpec]:
    """Validate a list of demonstrations for the model; return (obs_dim, action spec).

    Raises:
        UserError: no demonstrations, or inconsistent observation / action shapes or types.
    """
    if len(trajs) == 0:
        raise UserError("no demonstrations were given; pass a dataset with at least one episode.")
    obs_dims = {int(np.prod(np.shape(t.obs)[1:], dtype=np.int64)) for t in trajs}
    if len(obs_dims) != 1:
        raise UserError(f"demonstrations have different observation sizes {sorted(obs_dims)}; use one environment.")
    kinds = {t.discrete for t in trajs}
    if len(kinds) != 1:
        raise UserError("demonstrations mix discrete and continuous actions; use one environment.")
    if action_spec is None:
        acts = np.concatenate([np.asarray(t.acts).reshape(len(t), -1) for t in trajs])
        action_spec = ActionSpec.from_actions(acts[:, 0] if trajs[0].discrete else acts)
    if action_spec.discrete != trajs[0].discrete:
        kind = "discrete" if action_spec.discrete else "continuous"
        raise UserError(f"the action space is {kind} but the demonstrations' actions are not; check the dataset.")
    for t in trajs:
        acts = np.asarray(t.acts)
        if action_spec.discrete:
            if acts.reshape(len(t), -1).shape[1] != 1 or acts.min() < 0 or acts.max() >= action_spec.dim:
                raise UserError(f"discrete actions must be indices in [0, {action_spec.dim}); check the dataset.")
        elif acts.reshape(len(t), -1).shape[1] != action_spec.dim:
            raise UserError(f"expected {action_spec.dim}-dimensional actions, got shape {acts.shape[1:]}.")
    return obs_dims.pop(), action_spec


def pad_demos(trajs: Sequence[Trajectory], model: HierarchicalPolicy, device: torch.device) -> DemoBatch:
    """Pad every demonstration to the longest and normalise observations with the model's normaliser."""
    t_max = max(len(t) for t in trajs)
    n, d = len(trajs), model.obs_dim
    obs = np.zeros((n, t_max, d), np.float32)
    mask = np.zeros((n, t_max), np.float32)
    if model.action.discrete:
        acts: np.ndarray = np.zeros((n, t_max), np.int64)
    else:
        acts = np.zeros((n, t_max, model.action.dim), np.float32)
    for i, t in enumerate(trajs):
        T = len(t)
        obs[i, :T] = np.asarray(t.obs[:T], np.float32).reshape(T, d)
        acts[i, :T] = np.asarray(t.acts).reshape(acts[i, :T].shape)
        mask[i, :T] = 1.0
    with torch.no_grad():
        obs_n = model.normalizer.to(device)(torch.as_tensor(obs, device=device))
    mask_t = torch.as_tensor(mask, device=device)
    return DemoBatch(obs_n * mask_t[..., None], torch.as_tensor(acts, device=device), mask_t)


# ------------------------------------------------------------------------------------------------ loss
def gumbel_softmax_chain(q: MacroPolicy, obs_n: torch.Tensor, tau: float, hard: bool = False,
                         generator: torch.Generator | None = None,
                         gumbel: torch.Tensor | None = None, bptt: bool = False) -> tuple[torch.Tensor, torch.Tensor]:
    """Draw relaxed codes c~_0 .. c~_{T-1} sequentially from q(. | s_t, c~_{t-1}).

    Args:
        q: the macro-policy (`MacroPolicy`: a ReLU MLP on [obs_n, prev] whose layers are read directly).
        obs_n: (B, T, obs_dim) normalised observations.
        tau: Gumbel-softmax temperature.
        hard: straight-through: the forward pass uses exact one-hots (also as the next step's previous code),
            the backward pass the relaxed sample's gradient.
        generator: source of the Gumbel noise.
        gumbel: (B, T, K) Gumbel(0, 1) noise to use instead of drawing it (tests, reproductions).
        bptt: backpropagate through q's previous-code input too: the exact gradient of the sequential samples,
            through a hand-written backward loop. False (the default) draws the chain without gradient, then
            recomputes every step's logits from the sampled previous codes in one batched pass: the same samples
            and the same gradient except the path from c~_{t-1} into q(. | s_t, c~_{t-1}).

    Returns:
        `(logits, codes)`, both (B, T, K): q's logits at each step (given the sampled previous code) and the
        relaxed (or straight-through hard) samples. Gradients reach q through both.
    """
    linears = [m for m in q.net if isinstance(m, nn.Linear)]
    first, middle, last = linears[0], linears[1:-1], linears[-1]
    B, T, D = obs_n.shape
    K = last.out_features
    # Everything that does not depend on the previous code is computed for all steps at once, time-major.
    pre = F.linear(obs_n, first.weight[:, :D], first.bias).transpose(0, 1)
    if gumbel is None:
        u = torch.rand((T, B, K), generator=generator, device=obs_n.device).clamp_(1e-10, 1.0 - 1e-7)
        gumbel_tm = -torch.log(-torch.log(u))
    else:
        gumbel_tm = gumbel.transpose(0, 1)
    noise = (last.bias + gumbel_tm) / tau
    mids = [t for m in middle for t in (m.weight, m.bias)]
    if bptt:
        codes, h_last = _GumbelChain.apply(hard, pre, first.weight[:, D:], last.weight / tau, noise, *mids)
        logits = F.linear(h_last, last.weight, last.bias)
        return logits.transpose(0, 1), codes.transpose(0, 1)
    with torch.no_grad():
        fed = _sample_chain(hard, pre, first.weight[:, D:], last.weight / tau, noise, *mids)
    prev = torch.cat([torch.zeros_like(fed[:1]), fed[:-1]]).transpose(0, 1)
    logits = q(obs_n, prev)
    codes = ((logits + gumbel_tm.transpose(0, 1)) / tau).softmax(-1)
    if hard:
        codes = F.one_hot(codes.argmax(-1), K).to(codes.dtype) + (codes - codes.detach())
    return logits, codes


def _sample_chain(hard: bool, pre: torch.Tensor, w_prev: torch.Tensor, w_out: torch.Tensor, noise: torch.Tensor,
                  *mids: torch.Tensor) -> torch.Tensor:
    """The sampling loop of `_GumbelChain` alone (no gradient, nothing kept): the codes fed forward (T, B, K)."""
    K = w_out.shape[0]
    pairs = [(mids[i].t(), mids[i + 1]) for i in range(0, len(mids), 2)]
    w_prev_t, w_out_t = w_prev.t(), w_out.t()
    prev = pre.new_zeros(pre.shape[1], K)
    fed = []
    for pre_t, noise_t in zip(pre.unbind(0), noise.unbind(0), strict=True):
        h = torch.addmm(pre_t, prev, w_prev_t).relu_()
        for w_t, b in pairs:
            h = torch.addmm(b, h, w_t).relu_()
        prev = torch.addmm(noise_t, h, w_out_t).softmax(-1)
        if hard:
            prev = F.one_hot(prev.argmax(-1), K).to(prev.dtype)
        fed.append(prev)
    return torch.stack(fed)


class _GumbelChain(torch.autograd.Function):
    """The sequential part of `gumbel_softmax_chain` as one autograd node with hand-written backpropagation.

    Per step t: h_1 = relu(pre_t + prev_{t-1} @ w_prev.T), h_i = relu(h_{i-1} @ w_i.T + b_i),
    y_t = softmax(h_L @ w_out.T + noise_t), prev_t = y_t (or its one-hot when `hard`, straight-through).

    Why by hand: the loop is the whole cost of pre-training, and on a CPU that cost is the number of tiny tensor
    operations per step. The backward loop below carries only the gradient flowing into the previous code (six
    operations a step); every weight gradient is then one matrix product over all steps. Outputs: the codes fed
    forward (T, B, K) and the last hidden layer (T, B, H_L), from which the caller computes q's logits with
    ordinary autograd. Checked against plain autograd in tests/test_vae.py.
    """

    @staticmethod
    def forward(ctx: Any, hard: bool, pre: torch.Tensor, w_prev: torch.Tensor, w_out: torch.Tensor,
                noise: torch.Tensor, *mids: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        T, B, _ = pre.shape
        K = w_out.shape[0]
        pairs = [(mids[i].t(), mids[i + 1]) for i in range(0, len(mids), 2)]
        w_prev_t, w_out_t = w_prev.t(), w_out.t()
        prev = pre.new_zeros(B, K)
        layers: list[list[torch.Tensor]] = [[] for _ in range(len(pairs) + 1)]
        soft, fed = [], []
        for pre_t, noise_t in zip(pre.unbind(0), noise.unbind(0), strict=True):
            h = torch.addmm(pre_t, prev, w_prev_t).relu_()
            layers[0].append(h)
            for i, (w_t, b) in enumerate(pairs):
                h = torch.addmm(b, h, w_t).relu_()
                layers[i + 1].append(h)
            y = torch.addmm(noise_t, h, w_out_t).softmax(-1)
            soft.append(y)
            prev = F.one_hot(y.argmax(-1), K).to(y.dtype) if hard else y
            fed.append(prev)
        hs = [torch.stack(hl) for hl in layers]
        y_soft = torch.stack(soft)
        y_fed = torch.stack(fed) if hard else y_soft
        ctx.save_for_backward(y_soft, y_fed, w_prev, w_out, *hs, *mids)
        ctx.n_mid = len(pairs)
        return y_fed, hs[-1]

    @staticmethod
    def backward(ctx: Any, g_codes: torch.Tensor, g_hidden: torch.Tensor) -> tuple[torch.Tensor | None, ...]:
        y_soft, y_fed, w_prev, w_out, *rest = ctx.saved_tensors
        n_mid = ctx.n_mid
        hs, mids = rest[:n_mid + 1], rest[n_mid + 1:]
        weights = [mids[2 * i] for i in range(n_mid)]
        relu_grad = torch.ops.aten.threshold_backward
        y_steps, g_code_steps, g_hidden_steps = y_soft.unbind(0), g_codes.unbind(0), g_hidden.unbind(0)
        h_steps = [h.unbind(0) for h in hs]
        T = len(y_steps)
        g_z_steps: list[torch.Tensor] = []
        g_a_steps: list[list[torch.Tensor]] = [[] for _ in hs]
        g_y = g_code_steps[-1]
        for t in range(T - 1, -1, -1):
            # softmax, then each ReLU layer down to the first; straight-through uses the soft sample's Jacobian
            g_z = torch._softmax_backward_data(g_y, y_steps[t], -1, g_y.dtype)
            g_z_steps.append(g_z)
            g_h = torch.addmm(g_hidden_steps[t], g_z, w_out)
            for i in range(n_mid, 0, -1):
                g_a = relu_grad(g_h, h_steps[i][t], 0.0)
                g_a_steps[i].append(g_a)
                g_h = g_a @ weights[i - 1]
            g_a = relu_grad(g_h, h_steps[0][t], 0.0)
            g_a_steps[0].append(g_a)
            if t > 0:  # the code fed at step t - 1 gets its own gradient plus what flowed back through q
                g_y = torch.addmm(g_code_steps[t - 1], g_a, w_prev)
        g_z_all = torch.stack(g_z_steps[::-1])
        g_a_all = [torch.stack(steps[::-1]) for steps in g_a_steps]
        prev_all = torch.cat([torch.zeros_like(y_fed[:1]), y_fed[:-1]])

        def outer(a: torch.Tensor, b: torch.Tensor) -> torch.Tensor:
            return a.reshape(-1, a.shape[-1]).t() @ b.reshape(-1, b.shape[-1])

        g_mids: list[torch.Tensor] = []
        for i in range(n_mid):
            g_mids += [outer(g_a_all[i + 1], hs[i]), g_a_all[i + 1].sum((0, 1))]
        return (None, g_a_all[0], outer(g_a_all[0], prev_all), outer(g_z_all, hs[-1]), g_z_all, *g_mids)


def categorical_kl(logits_q: torch.Tensor, logits_p: torch.Tensor) -> torch.Tensor:
    """KL(q || p) over the last axis for categorical logits."""
    log_q = logits_q.log_softmax(-1)
    return (log_q.exp() * (log_q - logits_p.log_softmax(-1))).sum(-1)


def smoothing_penalty(codes: torch.Tensor) -> torch.Tensor:
    """Per-step smoothing term 1 - c_{t-1} . c_t / max(|c_{t-1}|, |c_t|) for t >= 1: shape (..., T - 1).

    Zero when consecutive codes are the same one-hot, one for two different one-hots (paper appendix).
    """
    prev, cur = codes[..., :-1, :], codes[..., 1:, :]
    denom = torch.maximum(prev.norm(dim=-1), cur.norm(dim=-1)).clamp_min(1e-8)
    return 1.0 - (prev * cur).sum(-1) / denom


def vae_loss(model: HierarchicalPolicy, batch: DemoBatch, cfg: VAEConfig, tau: float,
             generator: torch.Generator | None = None, gumbel: torch.Tensor | None = None,
             warmup: float = 1.0) -> tuple[torch.Tensor, dict[str, float]]:
    """The VAE loss of one padded batch (per-step average) and its parts for logging.

    `generator` / `gumbel` are passed to `gumbel_softmax_chain`; `warmup` (in [0, 1]) scales the KL and smoothing
    weights (`VAEConfig.warmup`).
    """
    logits, codes = gumbel_softmax_chain(model.q, batch.obs_n, tau, cfg.hard, generator, gumbel, cfg.bptt)
    prev = torch.cat([torch.zeros_like(codes[:, :1]), codes[:, :-1]], 1)
    mask = batch.mask
    n_steps = mask.sum()
    recon = -(model.pi.dist(batch.obs_n, codes).log_prob(batch.acts) * mask).sum() / n_steps
    kl = (categorical_kl(logits, model.prior(prev)) * mask).sum() / n_steps
    smooth = (smoothing_penalty(codes) * mask[:, 1:]).sum() / n_steps
    total = recon + warmup * cfg.kl_weight * kl
    if cfg.smoothing_weight:
        total = total + warmup * cfg.smoothing_weight * smooth
    if cfg.entropy_weight:
        log_q = logits.log_softmax(-1)
        entropy = -((log_q.exp() * log_q).sum(-1) * mask).sum() / n_steps
        total = total - cfg.entropy_weight * entropy
    parts = {"losses/total": total.item(), "losses/recon": recon.item(), "losses/kl": kl.item(),
             "losses/smooth": smooth.item()}
    return total, parts


# -------------------------------------------------------------------------------------------- training
def pretrain(trajs: Sequence[Trajectory], cfg: VAEConfig, *, action_spec: ActionSpec | None = None, seed: int = 0,
             device: str | torch.device = "cpu", progress: bool = True,
             log_dir: str | Path | None = None) -> tuple[HierarchicalPolicy, dict[str, list[float]]]:
    """Fit the hierarchical policy (q, p, pi and the observation normaliser) to demonstrations as a VAE, then
    `polish` it when `cfg.polish_steps` > 0.

    Args:
        trajs: the demonstrations (unsegmented; oracle labels, if any, are not used).
        cfg: VAE settings (codes, epochs, batch size, weights, temperature schedule).
        action_spec: the action space's spec; inferred from the actions when None (discrete: max index + 1).
        seed: seeds the initial weights, the batch order and the Gumbel noise; same seed, same result (on CPU).
        device: torch device.
        progress: show a tqdm bar with epoch, losses and temperature.
        log_dir: when given, write `losses.csv` (one row per epoch) and TensorBoard events (`tb/`) there.

    Returns:
        `(model, history)`: the trained model in eval mode and per-epoch lists `epoch`, `losses/total`,
        `losses/recon`, `losses/kl`, `losses/smooth` (per-step averages over the epoch), `vae/tau`, `time/s`.
    """
    if cfg.codes < 1 or cfg.epochs < 0 or cfg.batch_size < 1:
        raise UserError("VAE settings need codes >= 1, epochs >= 0 and batch_size >= 1.")
    obs_dim, action_spec = check_demos(trajs, action_spec)
    dev = resolve_device(str(device))
    seed_everything(seed)
    gen = torch.Generator(device=dev).manual_seed(seed)
    if cfg.decoder_obs is not None and not 0 <= cfg.decoder_obs[0] < cfg.decoder_obs[1] <= obs_dim:
        raise UserError(f"decoder_obs {cfg.decoder_obs} is not a feature range within the {obs_dim} observation "
                        "features; give (start, stop) with 0 <= start < stop <= obs size.")
    model = HierarchicalPolicy(obs_dim, cfg.codes, action_spec, cfg.hidden, cfg.learn_prior,
                               pi_obs=None if cfg.decoder_obs is None else (cfg.decoder_obs[0], cfg.decoder_obs[1]))
    model.normalizer.fit(np.concatenate([np.asarray(t.obs, np.float64).reshape(len(t.obs), -1) for t in trajs]))
    model.to(dev).train()
    data = pad_demos(trajs, model, dev)
    params = [p for p in model.parameters() if p.requires_grad]
    opt = adam(params, cfg.lr)

    history: dict[str, list[float]] = {"epoch": [], **{k: [] for k in LOSS_KEYS}, "vae/tau": [], "time/s": []}
    n, total_steps = len(trajs), float(data.mask.sum().item())
    start = time.perf_counter()
    bar = _progress_bar(cfg.epochs, progress)
    for epoch in range(cfg.epochs):
        tau = cfg.tau(epoch)
        order = torch.randperm(n, generator=torch.Generator().manual_seed(seed * 100_003 + epoch))
        sums = dict.fromkeys(LOSS_KEYS, 0.0)
        for b in range(0, n, cfg.batch_size):
            batch = data[order[b:b + cfg.batch_size].to(dev)]
            loss, parts = vae_loss(model, batch, cfg, tau, gen, warmup=cfg.warmup(epoch))
            opt.zero_grad(set_to_none=True)
            loss.backward()
            if cfg.max_grad_norm is not None:
                nn.utils.clip_grad_norm_(params, cfg.max_grad_norm)
            opt.step()
            weight = float(batch.mask.sum().item()) / total_steps
            for k in LOSS_KEYS:
                sums[k] += parts[k] * weight
        if not math.isfinite(sums["losses/total"]):
            if bar is not None:
                bar.close()
            raise UserError(f"VAE training diverged (non-finite loss at epoch {epoch}); lower --vae.lr or check "
                            "the demonstrations for extreme values.")
        history["epoch"].append(epoch)
        for k in LOSS_KEYS:
            history[k].append(sums[k])
        history["vae/tau"].append(tau)
        history["time/s"].append(time.perf_counter() - start)
        if bar is not None:
            bar.update(1)
            bar.set_postfix(recon=f"{sums['losses/recon']:.3f}", kl=f"{sums['losses/kl']:.3f}",
                            smooth=f"{sums['losses/smooth']:.3f}", tau=f"{tau:.2f}", refresh=False)
    if bar is not None:
        bar.close()
    if cfg.polish_steps > 0:
        polish(model, trajs, cfg, seed=seed, progress=progress)
    if log_dir is not None:
        write_losses_csv(Path(log_dir) / "losses.csv", history)
        write_tensorboard(Path(log_dir), history)
    return model.eval(), history


def polish(model: HierarchicalPolicy, trajs: Sequence[Trajectory], cfg: VAEConfig, *, seed: int = 0,
           progress: bool = True, minibatch: int = 256) -> HierarchicalPolicy:
    """Sharpen pi and q on the VAE's own causal segmentation of `trajs` (`VAEConfig.polish_steps`); in place.

    The VAE's joint objective stops at a loose decoder (its few thousand steps share the codes' noise), and q
    only ever saw the expert's exact states. With the codes fixed to `segment_many`'s causal decoding, pi is
    fitted by maximum likelihood and q by cross-entropy on states jittered by `cfg.q_noise` feature stds.
    """
    from digail.algos.decode import segment_many

    dev = next(model.parameters()).device
    codes_per_demo = segment_many(model, trajs)
    obs = torch.as_tensor(np.concatenate([np.asarray(t.obs[:-1], np.float32).reshape(len(t.acts), -1)
                                          for t in trajs]), device=dev)
    acts = torch.as_tensor(np.concatenate([np.asarray(t.acts) for t in trajs]), device=dev)
    if not model.action.discrete:
        acts = acts.float().reshape(len(acts), -1)
    codes = torch.as_tensor(np.concatenate(codes_per_demo), device=dev)
    # q's targets anticipate each switch; its previous-code inputs stay the segmentation's, so the switching
    # state itself (previous code still the old one) keeps its target too
    q_codes = torch.as_tensor(np.concatenate([anticipate_switches(c, cfg.q_anticipate) for c in codes_per_demo]),
                              device=dev)
    start = model.codes  # index of the zero row: c_{-1}
    prevs = torch.as_tensor(np.concatenate([np.r_[start, c[:-1]] for c in codes_per_demo]), device=dev)
    table = torch.cat([torch.eye(model.codes, device=dev), torch.zeros(1, model.codes, device=dev)])
    with torch.no_grad():
        obs_n = model.normalizer(obs)
    code_1h, prev_1h = table[codes], table[prevs]
    model.train()
    params = [*model.pi.parameters(), *model.q.parameters()]
    opt = adam(params, cfg.polish_lr)
    schedule = torch.optim.lr_scheduler.CosineAnnealingLR(opt, cfg.polish_steps)
    gen = torch.Generator(device=dev).manual_seed(seed + 7919)
    bar = _progress_bar(cfg.polish_steps, progress, desc="polish", unit="step")
    for step in range(cfg.polish_steps):
        idx = torch.randint(0, len(obs_n), (minibatch,), generator=gen, device=dev)
        log_pi, _ = model.pi.log_prob_entropy(obs_n[idx], code_1h[idx], acts[idx])
        noisy = obs_n[idx]
        if cfg.q_noise > 0:
            noisy = noisy + cfg.q_noise * torch.randn(noisy.shape, generator=gen, device=dev)
        loss = -log_pi.mean() + F.cross_entropy(model.q(noisy, prev_1h[idx]), q_codes[idx])
        opt.zero_grad(set_to_none=True)
        loss.backward()
        opt.step()
        schedule.step()
        if bar is not None and step % 200 == 0:
            bar.update(min(200, cfg.polish_steps - step))
            bar.set_postfix(loss=f"{loss.item():.3f}", refresh=False)
    if bar is not None:
        bar.close()
    if not all(torch.isfinite(p).all() for p in params):
        raise UserError("the VAE polish diverged (non-finite weights); lower --vae.polish-lr or set "
                        "--vae.polish-steps 0.")
    return model.eval()


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


def _progress_bar(total: int, enabled: bool, desc: str = "VAE", unit: str = "epoch") -> Any:
    if not enabled:
        return None
    from tqdm.auto import tqdm

    return tqdm(total=total, desc=desc, unit=unit, mininterval=0.5, dynamic_ncols=True)


def write_losses_csv(path: Path, history: dict[str, list[float]]) -> None:
    """One row per epoch, one column per history key."""
    path.parent.mkdir(parents=True, exist_ok=True)
    keys = list(history)
    with open(path, "w", newline="") as f:
        writer = csv.writer(f)
        writer.writerow(keys)
        writer.writerows(zip(*(history[k] for k in keys), strict=True))


def write_tensorboard(log_dir: Path, history: dict[str, list[float]]) -> None:
    """Mirror the per-epoch history to TensorBoard under `log_dir/tb` (skipped when tensorboard is missing)."""
    try:
        from torch.utils.tensorboard import SummaryWriter
    except Exception:  # tensorboard not installed or broken: the CSV has everything
        return
    with SummaryWriter(str(Path(log_dir) / "tb")) as writer:
        for i, epoch in enumerate(history["epoch"]):
            for key in (*LOSS_KEYS, "vae/tau"):
                writer.add_scalar(key, history[key][i], int(epoch))
