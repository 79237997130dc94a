"""Label-free model selection for the VAE: which of several restarts to keep, and how many codes K to use.

Both choices are scored on **held-out demonstrations** (`heldout_split`) by the **description length** of their
actions under the model's own causal segmentation (`description_length`): the two-part code a receiver who sees
the states needs to rebuild the actions,

    DL = sum_t -log pi(a_t | s_t, c_t)  +  (number of switches) * (log T + log(K - 1))   per episode,

with c_t = argmax q(. | s_t, c_{t-1}), what `digail segment` reports. The first part rewards codes that explain
the actions; the second charges every switch what it costs to say where it happens (one of T steps) and to which
other code, so a model that flickers or that uses more codes than the data needs pays for it. Divided by the
held-out steps: nats per step, lower is better. Unlike the training ELBO it needs no Gumbel samples or
temperature, it scores exactly the segmentation the user gets, and it stays comparable across K (the ELBO's
KL to a learned prior is not: larger K buys a lower reconstruction for free).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import Any

import numpy as np
import torch

from digail.algos.decode import padded_obs, segment_many
from digail.data.trajectory import Trajectory
from digail.errors import UserError
from digail.nets.mlp import one_hot
from digail.nets.vae import HierarchicalPolicy


def check_selectable(n: int) -> None:
    """Refuse to choose K from fewer than two demonstrations: nothing would be held out to score the candidates on.

    Raises:
        UserError: when `n` < 2.
    """
    if n < 2:
        raise UserError(f"K cannot be chosen from {n} demonstration: `--codes auto` scores each K on held-out "
                        "demonstrations and needs at least two; pass --codes K.")


def heldout_split(n: int, fraction: float, seed: int) -> tuple[np.ndarray, np.ndarray]:
    """Indices (train, held_out) of `n` demonstrations: a random `fraction` (at least one, at most n - 1) held out.

    With a single demonstration both are that one (nothing to hold out).
    """
    if n < 2:
        return np.arange(n), np.arange(n)
    k = min(n - 1, max(1, round(fraction * n)))
    perm = np.random.default_rng(seed + 424_242).permutation(n)
    return np.sort(perm[k:]), np.sort(perm[:k])


@torch.no_grad()
def description_length(model: HierarchicalPolicy, trajs: Sequence[Trajectory]) -> dict[str, float]:
    """Label-free scores of `model`'s causal segmentation of `trajs` (see the module docstring).

    Returns:
        `dl_per_step` (the criterion, nats per step, lower is better), `nll_per_step` (-log pi alone),
        `switches_per_episode` and `codes_used` (distinct codes in the segmentation).
    """
    codes = segment_many(model, trajs)
    obs_n, lengths = padded_obs(model, trajs)
    nll = 0.0
    switch_cost = 0.0
    switches = 0
    for i, (t, c) in enumerate(zip(trajs, codes, strict=True)):
        T = len(t)
        acts = torch.as_tensor(np.asarray(t.acts), device=obs_n.device)
        if not model.action.discrete:
            acts = acts.float().reshape(T, -1)
        c_t = torch.as_tensor(c, device=obs_n.device)
        logp, _ = model.pi.log_prob_entropy(obs_n[i, :T], one_hot(c_t, model.codes), acts)
        nll -= float(logp.sum())
        n_sw = int(np.count_nonzero(np.diff(c)))
        switches += n_sw
        switch_cost += n_sw * (math.log(T) + math.log(max(model.codes - 1, 1)))
    steps = float(lengths.sum())
    return {"dl_per_step": (nll + switch_cost) / steps, "nll_per_step": nll / steps,
            "switches_per_episode": switches / len(trajs),
            "codes_used": float(len(np.unique(np.concatenate(codes))))}


def best_index(scores: Sequence[dict[str, Any]], key: str = "dl_per_step") -> int:
    """Index of the lowest `key` (the first on ties)."""
    return int(np.argmin([s[key] for s in scores]))


def smallest_used_within_one_se(curve: Sequence[dict[str, Any]], min_use: float) -> tuple[int, int]:
    """(index of the chosen entry, K) when each fit counts for the codes it uses alike (`by_codes_used`): the one
    standard error rule of `smallest_within_one_se` over the best fit of each number of codes used."""
    weighed = by_codes_used(curve, min_use) or list(range(len(curve)))
    pick = _smallest_within_one_se(curve, weighed)
    return pick, codes_used(curve[pick], min_use) or int(curve[pick]["codes"])


def weighed_entries(curve: Sequence[dict[str, Any]], min_use: float = 0.0) -> list[int]:
    """Indices of the curve's entries whose `least_used` (how many fitted demonstrations the least used code
    appears in, as a fraction of the most used code's count) reaches `min_use`; all of them when none does."""
    return [i for i, e in enumerate(curve) if e.get("least_used", 1.0) >= min_use] or list(range(len(curve)))


def codes_used(entry: dict[str, Any], min_use: float) -> int:
    """How many of a curve entry's codes are used alike: each appears in at least `min_use` times as many fitted
    demonstrations as the most used one (`code_demos`; an entry without it counts all its codes)."""
    counts = np.asarray(entry.get("code_demos", [1] * int(entry["codes"])), np.float64)
    return int((counts >= min_use * counts.max()).sum()) if counts.max() > 0 else 0


def by_codes_used(curve: Sequence[dict[str, Any]], min_use: float) -> list[int]:
    """Indices of the curve's entries that stand for each number of codes used alike (`codes_used`), in increasing
    number: where several fits use as many codes alike, the one with the lowest held-out description length.

    Why: hard EM asked for K codes may leave some to a few demonstrations (a slip, a regrasp) or to none, and then
    it has found a segmentation into fewer sub-tasks, sometimes a better one than the fit asked for that many (on
    Meta-World's hammer the fit asked for 5 codes uses 4 and describes the held-out actions in 2.5 nats a step
    less than the fit asked for 4, which merges two phases). Such a fit is evidence for the codes it uses."""
    best: dict[int, int] = {}
    for i, entry in enumerate(curve):
        used = codes_used(entry, min_use)
        if used > 0 and (used not in best or entry["dl_per_step"] < curve[best[used]]["dl_per_step"]):
            best[used] = i
    return [best[u] for u in sorted(best)]


def smallest_within_one_se(curve: Sequence[dict[str, Any]], min_use: float = 0.0) -> int:
    """Index of the smallest K whose held-out description length is within one standard error of the lowest.

    The curve's entries are in increasing K and carry `episode_dl` (nats per held-out episode, the same episodes
    for every K). The standard error is that of the per-episode difference to the lowest K (paired: the episodes
    differ far more from one another than the models do). Why not the lowest outright: past the true K the curve
    is flat to within noise (extra codes split a sub-task where it costs nothing), and its lowest point there is
    chance; the one-standard-error rule keeps the simplest model the data cannot tell from the best.

    `min_use`: only the entries `weighed_entries` keeps are weighed.
    """
    return _smallest_within_one_se(curve, weighed_entries(curve, min_use))


def _smallest_within_one_se(curve: Sequence[dict[str, Any]], weighed: Sequence[int]) -> int:
    """`smallest_within_one_se` over the entries `weighed` (indices into `curve`, in increasing order of the K they
    stand for)."""
    best = weighed[best_index([curve[i] for i in weighed])]
    ref = np.asarray(curve[best]["episode_dl"], np.float64)
    for i, entry in ((i, curve[i]) for i in weighed):
        diff = np.asarray(entry["episode_dl"], np.float64) - ref
        se = diff.std(ddof=1) / math.sqrt(len(diff)) if len(diff) > 1 else 0.0
        if diff.mean() <= se:
            return i
    return best
