"""A first segmentation for the VAE to start from: hard EM on switching linear sub-task policies (`VAEConfig.init`).

Why: the VAE's macro-policy q(c_t | s_t, c_{t-1}) never sees the actions, so early in training its relaxed codes
carry no information, the decoder learns to ignore them and the KL term pulls q onto the prior (collapse). On the
segmentation benchmark the plain VAE collapsed on both tasks it was run on (accuracy 0.27-0.53, KL 0). This module finds
a segmentation from the actions themselves, which q then imitates before the VAE's own training continues.

Model: each code k has a linear sub-task policy on the normalised state, a ~ N(W_k [s, 1], sigma^2) per action
dimension (continuous; least squares per code, one variance per dimension shared by all codes) or
softmax(W_k [s, 1]) (discrete; a few L-BFGS steps). A
segmentation costs the actions' negative log-likelihood under its codes plus, per switch, the nats needed to say
where it happens and to which code, log T + log(K - 1) (T: the mean episode length): the description length of
`digail.algos.model_selection`, with no free parameter. Hard EM alternates the exact minimiser over
segmentations (Viterbi) and the policies' refit, from k-means clusters of (action, state) pairs.

Switch costs learned from the state (`switch_costs="learned"`, the default): each switch is charged
-log p(c_t | c_{t-1}, s_t) under a macro-policy fitted to the current segmentation (a softmax-linear model per
previous code), mixed half and half with the fixed model. A sub-task that ends where the state says so (a
waypoint reached) then switches almost for free, so two short legs no longer pay 2 (log T + log(K - 1)) nats more
than one merged code: on grid-six the fixed costs merge "right, then up" into one code (the start's accuracy
0.61), the learned ones keep the legs apart (0.98). The mixture bounds what an unpredicted switch costs (at most
log 2 nats more than the fixed model); an HMM's transition table, without the state or the mixture, let the codes
flicker (grid-large 0.98 -> 0.49, docs/experiments.md). The price: a switch the state does not announce (after
holding still in one place) now costs more than one it does, and the start may prefer the latter
(docs/experiments.md has a synthetic case; `switch_costs="fixed"` keeps the old costs).

Learned costs need a start near the sub-tasks. A macro-policy fitted to a flickering segmentation (k-means of
grid-six's actions gives a code per random action) makes flickering cheap, so EM from k-means first converges
with the fixed costs and only then learns them. The starts also include the ordered cut, every demonstration
cut into K consecutive pieces where its actions change most (`_ordered_pieces`), from which EM learns the costs
at once: on grid-six that start alone finds the legs.

The variance is shared because the codes should differ in what the expert does, not in how precisely a linear
policy predicts it: with a variance per code, a code that gathers the steps whose actions are nearly exactly
predictable earns up to -0.5 log(floor) nats per dimension and step, and on deterministic experts that pays for
splitting by the actions' size. On FetchPickAndPlace (K = 2 against pick / place) it split holding still from
moving (accuracy 0.71); with one shared variance it splits pick from place (0.96), the rest of the benchmark as
before (docs/experiments.md).

Capped costs (`outlier_share`, 1e-3 by default): each continuous action dimension's likelihood is a mixture of the
Gaussian and, with weight 1e-3, a uniform over the dimension's range in the demonstrations, so a step no linear
policy predicts costs at most about -log(1e-3 / range) nats per dimension. The policies are still fitted by least
squares; only the segmentation's costs are capped. Why: with the shared variance at its floor, one step whose
binary gripper command a code gets wrong cost 2^2 / (2 x 1e-4) = 20 000 nats, so on Fetch K = 4 the two closing
steps of every grasp bought a code of their own and reach merged with descend (0.854); capped, the start keeps
the four phases (0.935) and pick / place stays 0.960 (docs/experiments.md).

Sub-task models (`model`, `VAEConfig.init_model`; `MODELS`): `linear`, the policies above on [s_n, 1]; `rff`, the
same policies on [s_n, z(s_n), 1] with random Fourier features z (`_FeatureMap`), so a code's action is a smooth
function of the state. The segmentation machinery (Viterbi, switch costs, capped costs) is the same for both. The
K curve (`heldout_codes_curve`) scores either on held-out demonstrations, so the richer model pays for what it
costs: features that only memorise the fitted demonstrations predict the held-out ones worse. `linear` stays the
default for both: measured on the segmentation benchmark, `rff` puts a curved sub-task into one code but lets one
code explain several sub-tasks where the position tells the action (docs/howto/choosing-k.md).

Linear sub-task policies are the point: a network sees enough of the state to fit the whole demonstration with
one code, and then no segmentation explains the actions better than none; a linear policy per code cannot, so
the codes must carry what differs between sub-tasks.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import Any

import numpy as np

from digail.algos.segment_models import _design, _LinearPolicies, _pairs, _Transitions
from digail.algos.segment_search import (
    _action_features,
    _by_episode,
    _kmeans,
    _ordered_pieces,
    _viterbi,
    _viterbi_trans,
)
from digail.data.trajectory import Trajectory

OUTLIER_SHARE = 1e-3
"""Share of each continuous action dimension's likelihood that is uniform over the dimension's range (module
docstring, "Capped costs")."""


MODELS = ("linear", "rff")
"""the sub-task policy models of the start (`VAEConfig.init_model`; module docstring, "Sub-task models")"""


class _FeatureMap:
    """What a sub-task policy sees of the normalised state: `linear`, [s_n, 1]; `rff`, [s_n, z(s_n), 1] with
    `n_features` random Fourier features z_j = sqrt(2) cos(w_j . s_n + b_j), w_j ~ N(0, I / h^2), b_j ~ U(0, 2 pi),
    whose bandwidth h is `bandwidth_scale` times the median distance between states (the median heuristic), so
    a policy linear in them is a smooth function of the state at the scale the states spread over. The random
    features are drawn from a generator of their own, seeded by `seed`, and fitted once on the demonstrations the
    model is fitted to (the held-out ones of the K curve are mapped with the same features)."""

    def __init__(self, model: str, n_features: int = 64, bandwidth_scale: float = 0.5, seed: int = 0) -> None:
        if model not in MODELS:
            raise ValueError(f"unknown sub-task model {model!r}; choose one of {', '.join(MODELS)}.")
        self.model, self.n_features, self.bandwidth_scale, self.seed = model, n_features, bandwidth_scale, seed
        self.freq = np.zeros((0, 0))
        self.phase = np.zeros(0)

    def fit(self, x: np.ndarray) -> _FeatureMap:
        """Draw the random features for the rows `x` ([s_n, 1], as `_design` gives them)."""
        if self.model == "rff":
            s = x[:, :-1]
            rng = np.random.default_rng(self.seed + 7_919)
            sub = s[rng.choice(len(s), min(len(s), 1000), replace=False)]
            dist = np.sqrt(((sub[:, None] - sub[None]) ** 2).sum(-1))
            h = self.bandwidth_scale * float(np.median(dist[np.triu_indices(len(sub), 1)])) if len(sub) > 1 else 1.0
            h = h if h > 1e-8 else 1.0
            self.freq = rng.normal(size=(s.shape[1], self.n_features)) / h
            self.phase = rng.uniform(0, 2 * math.pi, self.n_features)
        return self

    def __call__(self, x: np.ndarray) -> np.ndarray:
        if self.model == "linear":
            return x
        z = math.sqrt(2) * np.cos(x[:, :-1] @ self.freq + self.phase)
        return np.c_[x[:, :-1], z, x[:, -1:]]


def hard_em_segmentation(trajs: Sequence[Trajectory], codes: int, discrete: bool, *, seed: int = 0,
                         rounds: int = 30, starts: int = 4, ridge: float = 1.0,
                         shared_variance: bool = True, switch_costs: str = "learned",
                         outlier_share: float = OUTLIER_SHARE, model: str = "linear",
                         actions: str = "auto") -> list[np.ndarray]:
    """Codes (one (T_i,) int64 array per demonstration) of the switching-linear-policy segmentation (module
    docstring): from K equal consecutive pieces, from the ordered cut (learned switch costs only), from
    `starts` - 1 k-means starts (`_hard_em`) and, with learned switch costs and `actions="auto"`, from more codes
    merged down to K (`_merged_down`), up to `rounds` of Viterbi and refit each (stopping when nothing changes);
    the segmentation with the shortest description length wins. `shared_variance=False`: one action
    variance per code (the first version, kept for the runs made with it); `switch_costs="fixed"`: log T +
    log(K - 1) nats per switch throughout (also kept for the runs made with it); `outlier_share`: the share of
    each continuous action dimension's likelihood that is uniform over its range (0: plain Gaussian, as the
    presets' runs were made); `model`: the sub-task policies' features (`MODELS`, module docstring); `actions`:
    how continuous actions are modelled (`segment_models.ACTION_MODELS`: `auto` reads clipped and few-valued
    dimensions off the data)."""
    rng = np.random.default_rng(seed)
    best: tuple[float, list[np.ndarray]] | None = None
    # fixed switch costs keep the starts their runs were made with
    firsts = ["chunks", *(["ordered"] if switch_costs == "learned" else []), *["kmeans"] * (starts - 1)]
    for first in firsts:
        cost, seg = _hard_em(trajs, codes, discrete, rng, rounds, first=first, ridge=ridge,
                             shared_variance=shared_variance, switch_costs=switch_costs, outlier_share=outlier_share,
                             model=model, seed=seed, actions=actions)
        if best is None or cost < best[0]:
            best = (cost, seg)
    if switch_costs == "learned" and codes > 1 and actions == "auto":
        cost, seg = _merged_down(trajs, codes, discrete, rng, rounds, ridge=ridge, shared_variance=shared_variance,
                                 outlier_share=outlier_share, model=model, seed=seed, actions=actions)
        if best is None or cost < best[0]:
            best = (cost, seg)
    assert best is not None
    return best[1]


MERGE_EXTRA = 4
"""`_merged_down` starts from K + min(K, MERGE_EXTRA) codes"""


def _merged_down(trajs: Sequence[Trajectory], codes: int, discrete: bool, rng: np.random.Generator, rounds: int,
                 **kw: Any) -> tuple[float, list[np.ndarray]]:
    """A start from above: hard EM with more codes than asked for (K + min(K, `MERGE_EXTRA`), from the equal and
    the ordered pieces), then, one code at a time, the two codes whose merged policy costs least over their steps
    become one and hard EM runs again from there, until K codes are left. Returns (description length, codes).

    Why: from K pieces or k-means, hard EM can settle where two sub-tasks that differ little (Meta-World's hammer:
    above the hammer, then onto it, 7 cm lower) share a code and another sub-task is cut in two, although the
    segmentation with the sub-tasks apart describes the actions in far fewer nats (docs/experiments.md). With
    more codes than sub-tasks both are apart at first; the merges then join what differs least."""
    fine = codes + min(codes, MERGE_EXTRA)
    best: tuple[float, list[np.ndarray]] | None = None
    for first in ("chunks", "ordered"):
        cost, seg = _hard_em(trajs, fine, discrete, rng, rounds, first=first, **kw)
        if best is None or cost < best[0]:
            best = (cost, seg)
    assert best is not None
    cost, seg = best
    p_all, a_all, n_act = _policy_design(trajs, discrete, kw["model"], kw["seed"])
    bounds = np.cumsum([0, *[len(t) for t in trajs]])
    for k in range(fine, codes, -1):
        flat = np.concatenate(seg)
        policies = _LinearPolicies(k, p_all.shape[1], n_act, discrete, kw["ridge"], kw["shared_variance"],
                                   kw["outlier_share"], kw["actions"])
        policies.fit(p_all, a_all, flat)
        own = -policies.loglik(p_all, a_all)[np.arange(len(flat)), flat]
        per_code = np.bincount(flat, weights=own, minlength=k)
        pair, rise = (k - 2, k - 1), math.inf
        for i in range(k):
            for j in range(i + 1, k):
                rows = (flat == i) | (flat == j)
                if not rows.any():  # two unused codes: merging them costs nothing
                    pair, rise = (i, j), -math.inf
                    continue
                merged = -float(_one_policy(policies, i, p_all[rows], a_all[rows]).sum())
                if merged - per_code[i] - per_code[j] < rise:
                    pair, rise = (i, j), merged - per_code[i] - per_code[j]
        i, j = pair
        flat = np.where(flat == j, i, flat)
        flat = np.where(flat > j, flat - 1, flat)
        start = [flat[bounds[e]:bounds[e + 1]] for e in range(len(trajs))]
        cost, seg = _hard_em(trajs, k - 1, discrete, rng, rounds, start=start, **kw)
    return cost, seg


def _one_policy(like: _LinearPolicies, code: int, x: np.ndarray, a: np.ndarray) -> np.ndarray:
    """Each row's log-likelihood under one policy fitted to all of `x`, `a` from code `code`'s policy of `like`,
    with the noise level, the action dimensions' kinds and the ranges of `like` (so merges of different pairs
    compare)."""
    one = _LinearPolicies(1, x.shape[1], like.w.shape[2], like.discrete,
                          1.0, like.shared_variance, like.outlier_share, like.actions)
    one.ridge = like.ridge
    one.kinds = like.kinds
    one.w[0] = like.w[code]
    one.w_values = {d: w[code:code + 1].copy() for d, w in like.w_values.items()}
    one.fit(x, a, np.zeros(len(x), np.int64))
    one.log_var[:], one.log_span = like.log_var[:1], like.log_span
    return one.loglik(x, a)[:, 0]


def _policy_design(trajs: Sequence[Trajectory], discrete: bool, model: str, seed: int
                   ) -> tuple[np.ndarray, np.ndarray, int]:
    """What the sub-task policies see of every step ([s_n, 1] through the feature map `model`), the actions and
    the number of discrete actions (or action dimensions)."""
    x_all, a_all, n_act, _, _ = _design(trajs, discrete)
    return _FeatureMap(model, seed=seed).fit(x_all)(x_all), a_all, n_act


def piece_em_segmentation(trajs: Sequence[Trajectory], pieces: Sequence[np.ndarray], codes: int, discrete: bool, *,
                          seed: int = 0, ridge: float = 1.0, starts: int = 8, rounds: int = 30,
                          outlier_share: float = OUTLIER_SHARE, model: str = "linear",
                          actions: str = "auto") -> list[np.ndarray]:
    """Codes (one (T_i,) int64 array per demonstration) when every piece of a demonstration takes one code: hard EM
    over the pieces (`pieces[i]` numbers demonstration i's steps by piece, e.g. Four Rooms' room visits, where an
    environment knows where its sub-tasks can change). Each round gives every piece the code whose linear policy
    explains its actions best (the summed log-likelihood) and refits the policies; the best of `starts` k-means
    starts on the state each piece ends in (the next observation of its last step) wins.

    Why the end state: a sub-task is where it leads (a corridor, the apple), and the pieces that reach one place
    share its policy, where the actions alone (the same moves towards different corridors) do not group them."""
    x, a, n_act, mean, std = _design(trajs, discrete)
    fmap = _FeatureMap(model, seed=seed).fit(x)
    x = fmap(x)
    ends = np.concatenate([(np.asarray(t.obs[1:len(t) + 1], np.float64).reshape(len(t), -1) - mean) / std
                           for t in trajs])
    local = [np.unique(np.asarray(p), return_inverse=True)[1].reshape(-1) for p in pieces]  # 0, 1, ... per demo
    offsets = np.cumsum([0, *[int(p.max()) + 1 for p in local]])
    piece = np.concatenate([p + offsets[i] for i, p in enumerate(local)])
    n_pieces = int(offsets[-1])
    end_of = np.zeros((n_pieces, ends.shape[1]))
    end_of[piece] = ends  # later steps overwrite earlier ones: each piece keeps its last step's next state
    used = np.unique(piece)
    rng = np.random.default_rng(seed)
    best: tuple[float, np.ndarray] | None = None
    for _ in range(starts):
        piece_codes = np.zeros(n_pieces, np.int64)
        piece_codes[used] = _kmeans(end_of[used], codes, rng)
        per_piece = np.zeros((n_pieces, codes))
        for _ in range(rounds):
            policies = _LinearPolicies(codes, x.shape[1], n_act, discrete, ridge,
                                       outlier_share=outlier_share, actions=actions)
            policies.fit(x, a, piece_codes[piece])
            per_piece = np.zeros((n_pieces, codes))
            np.add.at(per_piece, piece, policies.loglik(x, a))
            new = per_piece.argmax(1)
            if np.array_equal(new, piece_codes):
                break
            piece_codes = new
        cost = -float(per_piece[used, piece_codes[used]].sum())
        if best is None or cost < best[0]:
            best = (cost, piece_codes)
    assert best is not None
    flat = best[1][piece]
    bounds = np.cumsum([0, *[len(t) for t in trajs]])
    return [flat[bounds[i]:bounds[i + 1]] for i in range(len(trajs))]


def heldout_codes_curve(fit_on: Sequence[Trajectory], held: Sequence[Trajectory], candidates: Sequence[int],
                        discrete: bool, *, seed: int = 0, ridge: float = 1.0,
                        switch_costs: str = "fixed", outlier_share: float = OUTLIER_SHARE,
                        model: str = "linear", starts: int = 4, actions: str = "auto") -> list[dict[str, float]]:
    """Per K in `candidates`: the switching-linear-policy model fitted by hard EM on `fit_on`, scored on `held`
    by the description length of its best (Viterbi) segmentation there, in nats per held-out step. With learned
    switch costs the macro-policy fitted on `fit_on` charges the held-out switches.

    Why linear policies score K where the VAE's network cannot: a network sub-task policy sees enough of the state
    to explain the actions with fewer codes than there are sub-tasks (the square: 2 instead of 4), so extra codes
    buy it nothing; a linear policy per code needs one code per distinct behaviour. Each dict holds `codes`,
    `dl_per_step`, `least_used` (how many `fit_on` demonstrations the least used code of the fitted segmentation
    appears in, as a fraction of the most used code's count) and `episode_dl` (the held-out episodes' own
    description lengths in nats, for `model_selection.smallest_within_one_se`).
    """
    x_fit, a_fit, n_act, mean, std = _design(fit_on, discrete)
    x_held, a_held, _, _, _ = _design(held, discrete, n_act, mean, std)
    fmap = _FeatureMap(model, seed=seed).fit(x_fit)
    p_fit, p_held = fmap(x_fit), fmap(x_held)
    lengths = np.array([len(t) for t in held])
    bounds = np.cumsum([0, *lengths])
    fit_bounds = np.cumsum([0, *[len(t) for t in fit_on]])
    mean_len = float(np.mean([len(t) for t in [*fit_on, *held]]))
    curve = []
    for k in candidates:
        seg = (hard_em_segmentation(fit_on, k, discrete, seed=seed, ridge=ridge, switch_costs=switch_costs,
                                    outlier_share=outlier_share, model=model, starts=starts, actions=actions) if k > 1
               else [np.zeros(len(t), np.int64) for t in fit_on])
        policies = _LinearPolicies(k, p_fit.shape[1], n_act, discrete, ridge,
                                   outlier_share=outlier_share, actions=actions)
        policies.fit(p_fit, a_fit, np.concatenate(seg))
        flat = policies.loglik(p_held, a_held)
        if switch_costs == "learned":
            trans = _Transitions(k, x_fit.shape[1], mean_len)
            trans.fit(x_fit, seg, fit_bounds)
            logtrans = trans.logprob(x_held)
            codes = _viterbi_trans(_by_episode(flat, lengths), _by_episode(logtrans, lengths), lengths)
            prev, nxt, rows = _pairs(codes, bounds)
            switch_nats = -logtrans[rows, prev, nxt]
            per_episode = np.bincount(np.repeat(np.arange(len(lengths)), lengths - 1), weights=switch_nats,
                                      minlength=len(lengths))
        else:
            penalty = math.log(mean_len) + math.log(max(k - 1, 1))
            codes = _viterbi(_by_episode(flat, lengths), lengths, penalty)
            per_episode = np.array([penalty * np.count_nonzero(np.diff(c)) for c in codes])
        episode = np.array([-flat[bounds[i] + np.arange(lengths[i]), c].sum() for i, c in enumerate(codes)])
        episode = episode + per_episode
        curve.append({"codes": k, "dl_per_step": float(episode.sum() / lengths.sum()),
                      "switches_per_episode": float(np.mean([np.count_nonzero(np.diff(c)) for c in codes])),
                      "least_used": _least_used(seg, k),
                      "code_demos": _code_demos(seg, k),
                      "episode_dl": episode.tolist()})
    return curve


def _code_demos(seg: Sequence[np.ndarray], k: int) -> list[int]:
    """How many demonstrations each of k codes appears in."""
    return [sum(bool(np.any(c == j)) for c in seg) for j in range(k)]


def _least_used(seg: Sequence[np.ndarray], k: int) -> float:
    """How many demonstrations the least used of k codes appears in, as a fraction of the most used one's count."""
    counts = np.asarray(_code_demos(seg, k), np.float64)
    return float(counts.min() / counts.max()) if counts.max() > 0 else 0.0


def hard_em_from(trajs: Sequence[Trajectory], start: Sequence[np.ndarray], codes: int, discrete: bool, *,
                 rounds: int = 30, ridge: float = 1.0, switch_costs: str = "learned",
                 outlier_share: float = OUTLIER_SHARE, model: str = "linear",
                 actions: str = "auto") -> tuple[float, list[np.ndarray]]:
    """(description length in nats, codes) of hard EM started from the segmentation `start` (`rounds=0`: the
    cost of `start` itself). For diagnosis: started from oracle labels it shows whether the criterion ranks
    the truth above what the search finds."""
    return _hard_em(trajs, codes, discrete, np.random.default_rng(0), rounds, ridge=ridge,
                    start=[np.asarray(c, np.int64) for c in start], switch_costs=switch_costs,
                    outlier_share=outlier_share, model=model, actions=actions)


def _hard_em(trajs: Sequence[Trajectory], codes: int, discrete: bool, rng: np.random.Generator,
             rounds: int, first: str = "kmeans", ridge: float = 1e-3, shared_variance: bool = True,
             start: list[np.ndarray] | None = None, switch_costs: str = "learned",
             outlier_share: float = 0.0, model: str = "linear", seed: int = 0,
             actions: str = "gaussian") -> tuple[float, list[np.ndarray]]:
    """One hard-EM run: (description length in nats, codes per demonstration). It starts from `start` when given,
    else (`first`) from k-means clusters of (action, state) pairs, or from every demonstration cut into K
    consecutive pieces with codes 0, 1, ..., K - 1 in time: `chunks` of equal length, or the `ordered` cut the
    actions change most at (`_ordered_pieces`). The pieces are near the truth when sub-tasks come in one order,
    where k-means of the actions can settle on pieces of a curve instead (Circle-World) or on flickering codes
    (grid-six's random actions). With learned switch costs, EM from k-means runs with the fixed costs until
    nothing changes and then on with the learned ones (a macro-policy fitted to a flickering start would keep it
    flickering); from the pieces, which switch K - 1 times per demonstration, or from a given start it learns at
    once. The cost is then that of the learned model."""
    x_all, a_all, n_act, _, _ = _design(trajs, discrete)
    lengths = np.array([len(t) for t in trajs])
    bounds = np.cumsum([0, *lengths])
    a_feat = _action_features(a_all, n_act, discrete)
    if start is not None:
        seg = list(start)
    elif first == "chunks":
        seg = [np.minimum(np.arange(len(t)) * codes // len(t), codes - 1) for t in trajs]
    elif first == "ordered":
        seg = [_ordered_pieces(a_feat[bounds[i]:bounds[i + 1]], codes) for i in range(len(trajs))]
    else:
        # k-means on (action, state): the actions separate the sub-tasks, the state splits a repeated action
        labels = _kmeans(np.c_[a_feat, 0.5 * x_all[:, :-1]], codes, rng)
        seg = [labels[bounds[i]:bounds[i + 1]] for i in range(len(trajs))]
    fmap = _FeatureMap(model, seed=seed).fit(x_all)
    p_all = fmap(x_all)
    policies = _LinearPolicies(codes, p_all.shape[1], n_act, discrete, ridge,
                               shared_variance, outlier_share, actions)
    mean_len = float(np.mean(lengths))
    penalty = math.log(mean_len) + math.log(max(codes - 1, 1))
    trans = _Transitions(codes, x_all.shape[1], mean_len) if switch_costs == "learned" else None
    learning = trans is not None and (start is not None or first != "kmeans")

    def padded_loglik() -> np.ndarray:
        return _by_episode(policies.loglik(p_all, a_all), lengths)

    for _ in range(rounds):
        policies.fit(p_all, a_all, np.concatenate(seg))
        if learning:
            assert trans is not None
            trans.fit(x_all, seg, bounds)
            new = _viterbi_trans(padded_loglik(), _by_episode(trans.logprob(x_all), lengths), lengths)
        else:
            new = _viterbi(padded_loglik(), lengths, penalty)
        if all(np.array_equal(n, o) for n, o in zip(new, seg, strict=True)):
            if trans is None or learning:
                break
            learning = True
        seg = new
    policies.fit(p_all, a_all, np.concatenate(seg))
    flat_codes = np.concatenate(seg)
    cost = -float(policies.loglik(p_all, a_all)[np.arange(len(flat_codes)), flat_codes].sum())
    if trans is None:
        return cost + penalty * sum(int(np.count_nonzero(np.diff(c))) for c in seg), seg
    trans.fit(x_all, seg, bounds)
    prev, nxt, rows = _pairs(seg, bounds)
    return cost - float(trans.logprob(x_all)[rows, prev, nxt].sum()), seg
