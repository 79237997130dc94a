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

Choices beyond the paper (the gradient stopped at q's previous-code input unless `bptt`, a warm-up of the KL and
smoothing weights, an entropy bonus on q, the polish) are measured in docs/experiments.md.

Speed: only the sampling chain is sequential (`digail.algos.gumbel`; its fast path `digail.algos.fast.gumbel_chain`);
the decoder, the KL, the smoothing and entropy terms are evaluated on the whole (batch, time) block at once.
Demonstrations of different lengths are padded and masked. With soft samples and the gradient stopped at q's
previous-code input (every preset), training on the fast path takes the loss's gradient from
`digail.algos.fast.vae_grad` (one scripted pass, backpropagation by hand) instead of autograd.
"""

from __future__ import annotations

import csv
import dataclasses
import math
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import torch

from digail.algos import fast
from digail.algos.fast.vae_grad import VAEGrad
from digail.algos.gumbel import gumbel_softmax_chain
from digail.algos.model_selection import (
    best_index,
    by_codes_used,
    check_selectable,
    codes_used,
    description_length,
    heldout_split,
    smallest_used_within_one_se,
    smallest_within_one_se,
    weighed_entries,
)
from digail.algos.optim import adam, clipped_step
from digail.algos.polish import fit_to_codes, polish
from digail.algos.segment_init import hard_em_segmentation, heldout_codes_curve, piece_em_segmentation
from digail.config import VAEConfig
from digail.data.trajectory import Trajectory
from digail.data.validation import check_demos
from digail.errors import UserError
from digail.nets.policy import ActionSpec
from digail.nets.vae import HierarchicalPolicy
from digail.utils import progress_bar, resolve_device, seed_everything

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


class FusedVAEStep:
    """`vae_loss` and its backward pass for soft samples without bptt, through `VAEGrad`: the same Gumbel draws
    from `generator` as `gumbel_softmax_chain`, the gradient left in each parameter's `.grad`."""

    def __init__(self, model: HierarchicalPolicy, cfg: VAEConfig) -> None:
        self.grad, self.cfg = VAEGrad(model), cfg

    def step(self, batch: DemoBatch, tau: float, warmup: float, generator: torch.Generator) -> dict[str, float]:
        B, T = batch.mask.shape
        K = self.cfg.codes
        u = torch.rand((T, B, K), generator=generator, device=batch.mask.device).clamp_(1e-10, 1.0 - 1e-7)
        cfg = self.cfg
        return self.grad(batch.obs_n.transpose(0, 1).contiguous(), batch.acts.transpose(0, 1).contiguous(),
                         batch.mask.t().contiguous(), -torch.log(-torch.log(u)), tau, warmup * cfg.kl_weight,
                         warmup * cfg.smoothing_weight, cfg.entropy_weight)


# -------------------------------------------------------------------------------------------- training
def pretrain(trajs: Sequence[Trajectory], cfg: VAEConfig, *, action_spec: ActionSpec | None = None, seed: int = 0,
             device: str | torch.device = "cpu", progress: bool = True, log_dir: str | Path | None = None,
             before_polish: Callable[[HierarchicalPolicy], None] | None = None,
             restart_log: list[dict[str, float]] | None = None,
             pieces: Callable[[np.ndarray], np.ndarray] | None = None
             ) -> tuple[HierarchicalPolicy, dict[str, list[float]]]:
    """Fit the hierarchical policy (q, p, pi and the observation normaliser) to demonstrations as a VAE, then
    `polish` it when `cfg.polish_steps` > 0.

    With `cfg.restarts` = N > 1, N VAEs (seeds `seed` .. `seed` + N - 1) train on the demonstrations less a
    held-out share (`cfg.heldout_fraction`), and the one whose causal segmentation describes the held-out
    actions in the fewest nats (`digail.algos.model_selection`) is kept, then polished on all of them.

    Args:
        trajs: the demonstrations (unsegmented; oracle labels, if any, are not used).
        cfg: VAE settings (codes, epochs, batch size, weights, temperature schedule).
        action_spec: the action space's spec; inferred from the actions when None (discrete: max index + 1).
        seed: seeds the initial weights, the batch order and the Gumbel noise; same seed, same result (on CPU).
        device: torch device.
        progress: show a tqdm bar with epoch, losses and temperature.
        log_dir: when given, write `losses.csv` (one row per epoch) and TensorBoard events (`tb/`) there.
        before_polish: called with the model (in eval mode) once the VAE epochs are done and before the polish
            (also when there is none): the VAE's own segmentation, e.g. to compare smoothing weights, is only
            visible there, since the polish refits q to it. It must not change the model or draw random numbers.
        restart_log: with `cfg.restarts` > 1, receives one dict per restart (its seed and held-out scores,
            `digail.algos.model_selection.description_length`); the lowest `dl_per_step` is kept.
        pieces: with `cfg.init_pieces == "env"`, the environment's cut of a demonstration's (T, D) observations
            into pieces that take one code each in the start (`digail.envs.registry.EnvSpec.init_pieces`).

    Returns:
        `(model, history)`: the trained model in eval mode and per-epoch lists `epoch`, `losses/total`,
        `losses/recon`, `losses/kl`, `losses/smooth` (per-step averages over the epoch), `vae/tau`, `time/s`.
    """
    obs_dim, action_spec = check_demos(trajs, action_spec)
    dev = resolve_device(str(device))
    if cfg.decoder_obs is not None and not 0 <= cfg.decoder_obs[0] < cfg.decoder_obs[1] <= obs_dim:
        raise UserError(f"decoder_obs {cfg.decoder_obs} is not a feature range within the {obs_dim} observation "
                        "features; give (start, stop) with 0 <= start < stop <= obs size.")
    if cfg.init_obs is not None and not cfg.init_obs[1] <= obs_dim:
        raise UserError(f"--vae.init-obs {cfg.init_obs} is not a feature range within the {obs_dim} observation "
                        "features; give START STOP with 0 <= START < STOP <= obs size.")
    if cfg.init == "em" and cfg.init_pieces == "env" and pieces is None:
        raise UserError("--vae.init-pieces env needs an environment that cuts its demonstrations into pieces "
                        "(Four Rooms: its room visits) and this dataset's has none; use --vae.init-pieces steps.")
    if cfg.init == "labels" and cfg.codes > 1:
        label_codes(trajs, cfg.codes)  # refused before any training
    if cfg.restarts > 1:
        # every restart trains on the same demonstrations and is scored on the same held-out ones
        train_idx, held_idx = heldout_split(len(trajs), cfg.heldout_fraction, seed)
        fit_on, held = [trajs[i] for i in train_idx], [trajs[i] for i in held_idx]
        best: tuple[float, HierarchicalPolicy, dict[str, list[float]]] | None = None
        for r in range(cfg.restarts):
            model, history = _fit(fit_on, cfg, action_spec, obs_dim, seed + r, dev, progress, pieces)
            score = description_length(model, held)
            if restart_log is not None:
                restart_log.append({"seed": seed + r, **score})
            if best is None or score["dl_per_step"] < best[0]:
                best = (score["dl_per_step"], model, history)
        assert best is not None
        _, model, history = best
    else:
        model, history = _fit(trajs, cfg, action_spec, obs_dim, seed, dev, progress, pieces)
    if before_polish is not None:
        model.eval()
        before_polish(model)
        model.train()
    if cfg.polish_steps > 0:
        polish(model, trajs, cfg, seed=seed, progress=progress)
    if log_dir is not None:
        write_losses_csv(Path(log_dir) / "losses.csv", history)
        write_tensorboard(Path(log_dir), history)
    return model.eval(), history


def label_codes(trajs: Sequence[Trajectory], codes: int) -> list[np.ndarray]:
    """Each demonstration's sub-task labels as its codes (`--vae.init labels`), refused in one sentence where a
    demonstration has none or a label is not a code below `codes`."""
    out = []
    for i, t in enumerate(trajs):
        if t.subtasks is None:
            raise UserError(f"--vae.init labels reads each demonstration's sub-task labels, but episode {i} has "
                            "none; pass labelled demonstrations or use --vae.init em.")
        labels = np.asarray(t.subtasks)[:len(t.acts)].astype(np.int64)
        if len(labels) < len(t.acts) or labels.min() < 0 or labels.max() >= codes:
            raise UserError(f"--vae.init labels: episode {i} has labels from {labels.min()} to {labels.max()}, "
                            f"which {codes} codes cannot take one each; pass --codes {int(labels.max()) + 1} or more.")
        out.append(labels)
    return out


def auto_epochs(cfg: VAEConfig, n_demos: int) -> int:
    """`cfg.epochs`, or when that is None the epochs that give about `cfg.steps` gradient steps on `n_demos`
    demonstrations (at least one epoch): the work, and the temperature and warm-up schedules, then follow the
    number of updates, not the size of the data (0 when `cfg.steps` is 0)."""
    if cfg.epochs is not None:
        return cfg.epochs
    per_epoch = math.ceil(n_demos / cfg.batch_size)
    return 0 if cfg.steps == 0 else max(1, round(cfg.steps / per_epoch))


def _fit(trajs: Sequence[Trajectory], cfg: VAEConfig, action_spec: ActionSpec, obs_dim: int, seed: int,
         dev: torch.device, progress: bool, pieces: Callable[[np.ndarray], np.ndarray] | None = None
         ) -> tuple[HierarchicalPolicy, dict[str, list[float]]]:
    """One VAE training from the seed `seed` (`pretrain` without the restarts and the polish)."""
    seed_everything(seed)
    gen = torch.Generator(device=dev).manual_seed(seed)
    epochs = auto_epochs(cfg, len(trajs))
    model = HierarchicalPolicy(obs_dim, cfg.codes, action_spec, cfg.hidden, cfg.learn_prior,
                               decoder_obs=None if cfg.decoder_obs is None
                               else (cfg.decoder_obs[0], cfg.decoder_obs[1]))
    model.normalizer.fit(np.concatenate([np.asarray(t.obs, np.float64).reshape(len(t.obs), -1) for t in trajs]))
    model.to(dev).train()
    if cfg.init in ("em", "labels"):
        # one code has one segmentation (every step is code 0): the start is then plain behaviour cloning, which
        # the flat baselines need (the same decoder, data and steps as the K > 1 VAE, no codes to find)
        if cfg.codes == 1:
            first = [np.zeros(len(t.acts), np.int64) for t in trajs]
        elif cfg.init == "labels":
            first = label_codes(trajs, cfg.codes)
        else:
            first = _start(trajs, cfg, action_spec.discrete, seed, pieces)
        fit_to_codes(model, trajs, first, cfg.init_steps, cfg.polish_lr, seed=seed, progress=progress, desc="init")
        model.train()
    data = pad_demos(trajs, model, dev)
    params = [p for p in model.parameters() if p.requires_grad]
    opt = adam(params, cfg.lr)
    # soft samples without bptt (every preset): the loss and its gradient in one scripted pass (`VAEGrad`)
    fused = None if cfg.hard or cfg.bptt or not fast.enabled() else FusedVAEStep(model, cfg)

    history: dict[str, list[float]] = {"epoch": [], **{k: [] for k in LOSS_KEYS}, "vae/tau": [], "time/s": []}
    n, total_steps = len(trajs), float(data.mask.sum().item())
    start = time.perf_counter()
    bar = progress_bar(epochs, progress)
    for epoch in range(epochs):
        tau = cfg.tau(epoch, epochs)
        order = torch.randperm(n, generator=torch.Generator().manual_seed(seed * 100_003 + epoch))
        sums = dict.fromkeys(LOSS_KEYS, 0.0)
        for b in range(0, n, cfg.batch_size):
            batch = data[order[b:b + cfg.batch_size].to(dev)]
            if fused is None:
                loss, parts = vae_loss(model, batch, cfg, tau, gen, warmup=cfg.warmup(epoch, epochs))
                for p in params:
                    p.grad = None
                loss.backward()
            else:
                parts = fused.step(batch, tau, cfg.warmup(epoch, epochs), gen)
            clipped_step(opt, cfg.max_grad_norm)
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
            bar.set_postfix(recon=f"{sums['losses/recon']:.3f}", kl=f"{sums['losses/kl']:.3f}",
                            smooth=f"{sums['losses/smooth']:.3f}", tau=f"{tau:.2f}", refresh=False)
            bar.update(1)
    if bar is not None:
        bar.close()
    return model.eval(), history


def _start(trajs: Sequence[Trajectory], cfg: VAEConfig, discrete: bool, seed: int,
           pieces: Callable[[np.ndarray], np.ndarray] | None) -> list[np.ndarray]:
    """The hard-EM segmentation the VAE starts from (`cfg.init == "em"`), on the features `cfg.init_obs`."""
    seen = trajs
    if cfg.init_obs is not None:
        lo, hi = cfg.init_obs
        seen = [dataclasses.replace(t, obs=np.asarray(t.obs).reshape(len(t.obs), -1)[:, lo:hi]) for t in trajs]
    if cfg.init_pieces == "env":
        assert pieces is not None  # `pretrain` checked
        cuts = [pieces(np.asarray(t.obs)[:len(t)]) for t in trajs]
        return piece_em_segmentation(seen, cuts, cfg.codes, discrete, seed=seed, ridge=cfg.start_ridge(discrete),
                                     outlier_share=cfg.init_outlier_share, model=cfg.init_model,
                                     actions=cfg.init_actions)
    return hard_em_segmentation(seen, cfg.codes, discrete, seed=seed, ridge=cfg.start_ridge(discrete),
                                shared_variance=cfg.init_variance == "shared", switch_costs=cfg.init_switch_costs,
                                outlier_share=cfg.init_outlier_share, model=cfg.init_model,
                                actions=cfg.init_actions)


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


def codes_curve(trajs: Sequence[Trajectory], cfg: VAEConfig, candidates: Sequence[int], discrete: bool, *,
                seed: int = 0) -> tuple[list[dict[str, Any]], int]:
    """(curve, index of the chosen fit) of the `linear` or `rff` criterion (`select_codes`): hard EM per K on the
    demonstrations less the held-out share `heldout_split` gives for `seed`, scored on that share. The chosen fit's
    `chosen_codes` is the K chosen: with `cfg.k_count` `used`, the codes it uses alike, which may be fewer than it
    was asked for."""
    train_idx, held_idx = heldout_split(len(trajs), cfg.heldout_fraction, seed)
    fit_on, held = [trajs[i] for i in train_idx], [trajs[i] for i in held_idx]
    # fixed switch costs: with learned ones the curve kept falling past the truth (grid-large: 7-8 for 3)
    curve: list[dict[str, Any]] = heldout_codes_curve(fit_on, held, candidates, discrete, seed=seed,
                                                      switch_costs="fixed", outlier_share=cfg.init_outlier_share,
                                                      model=cfg.k_criterion, actions=cfg.init_actions,
                                                      ridge=cfg.curve_ridge(discrete))
    if cfg.k_count == "used":
        pick, k = smallest_used_within_one_se(curve, cfg.k_min_use)
        weighed = by_codes_used(curve, cfg.k_min_use)
    else:
        pick = smallest_within_one_se(curve, cfg.k_min_use)
        weighed, k = weighed_entries(curve, cfg.k_min_use), int(curve[pick]["codes"])
    for i, entry in enumerate(curve):
        del entry["episode_dl"]  # the selection's working data, not worth keeping in config.json
        entry["used"] = codes_used(entry, cfg.k_min_use)
        entry["weighed"] = i in weighed
        entry["chosen"] = i == pick
    curve[pick]["chosen_codes"] = k
    return curve, pick


def select_codes(trajs: Sequence[Trajectory], cfg: VAEConfig, candidates: Sequence[int], *,
                 action_spec: ActionSpec | None = None, seed: int = 0, device: str | torch.device = "cpu",
                 progress: bool = True, log_dir: str | Path | None = None,
                 pieces: Callable[[np.ndarray], np.ndarray] | None = None
                 ) -> tuple[HierarchicalPolicy, dict[str, list[float]], list[dict[str, Any]]]:
    """Choose the number of codes K without labels: each K in `candidates` is fitted on the demonstrations less a
    held-out share and scored by the description length of the held-out actions (`model_selection`), then the
    chosen K is trained (and polished) on all demonstrations.

    `cfg.k_criterion` says which model is scored: `linear` or `rff`, hard EM's switching sub-task policies on
    random Fourier features of the state or on the state alone (the start's ridge unless `cfg.k_ridge` says
    otherwise; among the K whose codes are used alike, `cfg.k_min_use`, the smallest within one standard error of
    the lowest, `smallest_within_one_se`), or `vae`, a whole VAE per K (the lowest; the chosen VAE is kept and only
    polished on all demonstrations).

    The curve's linear policies cut at any step; `pieces` (`pretrain`'s) serves the VAEs' own start.

    Returns:
        `(model, history, curve)`: the chosen model, its training history and one dict per candidate K
        (`codes`, `dl_per_step`, ... and `chosen`, true for the K kept).
    """
    _, action_spec = check_demos(trajs, action_spec)
    check_selectable(len(trajs))
    train_idx, held_idx = heldout_split(len(trajs), cfg.heldout_fraction, seed)
    fit_on, held = [trajs[i] for i in train_idx], [trajs[i] for i in held_idx]
    curve: list[dict[str, Any]] = []
    if cfg.k_criterion != "vae":
        curve, pick = codes_curve(trajs, cfg, candidates, action_spec.discrete, seed=seed)
        model, history = pretrain(trajs, dataclasses.replace(cfg, codes=int(curve[pick]["chosen_codes"])),
                                  action_spec=action_spec, seed=seed, device=device, progress=progress,
                                  log_dir=log_dir, pieces=pieces)
    else:
        kept: tuple[HierarchicalPolicy, dict[str, list[float]]] | None = None
        for k in candidates:
            fitted = pretrain(fit_on, dataclasses.replace(cfg, codes=k, polish_steps=0), action_spec=action_spec,
                              seed=seed, device=device, progress=progress, pieces=pieces)
            curve.append({"codes": k, **description_length(fitted[0], held)})
            if best_index(curve) == len(curve) - 1:  # only the best so far is kept in memory
                kept = fitted
        assert kept is not None
        pick = best_index(curve)
        model, history = kept
        if cfg.polish_steps > 0:
            polish(model, trajs, cfg, seed=seed, progress=progress)
        if log_dir is not None:
            write_losses_csv(Path(log_dir) / "losses.csv", history)
            write_tensorboard(Path(log_dir), history)
    for i, entry in enumerate(curve):
        entry["chosen"] = i == pick
    return model.eval(), history, curve
