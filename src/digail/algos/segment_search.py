"""The searches over segmentations of `digail.algos.segment_init`: the starts hard EM begins from (k-means, the
ordered cut) and its E-step, the Viterbi paths that minimise the cost under the fitted models.
"""

from __future__ import annotations

import math

import numpy as np


def _kmeans(z: np.ndarray, k: int, rng: np.random.Generator, iters: int = 30) -> np.ndarray:
    """Labels of k-means (k-means++ start) on the rows of `z`."""
    centres = [z[rng.integers(len(z))]]
    for _ in range(1, k):
        d2 = np.min([((z - c) ** 2).sum(1) for c in centres], 0)
        p = d2 / d2.sum() if d2.sum() > 0 else None
        centres.append(z[rng.choice(len(z), p=p)])
    c = np.array(centres)
    labels = np.zeros(len(z), np.int64)
    for _ in range(iters):
        labels = ((z[:, None, :] - c[None]) ** 2).sum(-1).argmin(1)
        for j in range(k):
            if np.any(labels == j):
                c[j] = z[labels == j].mean(0)
    return labels


def _viterbi(loglik: np.ndarray, lengths: np.ndarray, penalty: float) -> list[np.ndarray]:
    """Per episode, the codes minimising -sum_t loglik[t, c_t] + penalty * (number of switches).

    `loglik` is (B, T_max, K), zero beyond each episode's length (there every code scores alike, so the best
    code at the last real step stays the best to the end and the backtrack passes through unchanged). All
    episodes at once, one loop over time.
    """
    B, T, K = loglik.shape
    rows = np.arange(B)
    score = loglik[:, 0].copy()
    back = np.zeros((B, T, K), np.int64)
    for t in range(1, T):
        best_prev = score.argmax(1)
        switch = score[rows, best_prev] - penalty
        stay = score >= switch[:, None]
        back[:, t] = np.where(stay, np.arange(K)[None], best_prev[:, None])
        score = np.where(stay, score, switch[:, None]) + loglik[:, t]
    return _backtrack(score, back, lengths)


def _viterbi_trans(loglik: np.ndarray, logtrans: np.ndarray, lengths: np.ndarray) -> list[np.ndarray]:
    """Per episode, the codes maximising sum_t loglik[t, c_t] + sum_{t>0} logtrans[t, c_{t-1}, c_t].

    `loglik` is (B, T_max, K) and `logtrans` (B, T_max, K, K), both zero beyond each episode's length (so the
    path past the end keeps its code, as in `_viterbi`)."""
    B, T, K = loglik.shape
    score = loglik[:, 0].copy()
    back = np.zeros((B, T, K), np.int64)
    for t in range(1, T):
        cand = score[:, :, None] + logtrans[:, t]  # (B, from, to)
        back[:, t] = cand.argmax(1)
        score = np.take_along_axis(cand, back[:, t][:, None, :], 1)[:, 0] + loglik[:, t]
    return _backtrack(score, back, lengths)


def _backtrack(score: np.ndarray, back: np.ndarray, lengths: np.ndarray) -> list[np.ndarray]:
    """The Viterbi path per episode from the final (B, K) scores and the (B, T, K) back-pointers."""
    B, T, _ = back.shape
    rows = np.arange(B)
    path = np.empty((B, T), np.int64)
    path[:, -1] = score.argmax(1)
    for t in range(T - 1, 0, -1):
        path[:, t - 1] = back[rows, t, path[:, t]]
    return [path[i, :n].copy() for i, n in enumerate(lengths)]


def _by_episode(flat: np.ndarray, lengths: np.ndarray) -> np.ndarray:
    """(B, T_max, ...) of the per-step rows `flat` (sum(lengths), ...), one episode per row, zero past its end
    (what `_viterbi` and `_viterbi_trans` take)."""
    bounds = np.cumsum([0, *lengths])
    out = np.zeros((len(lengths), int(lengths.max()), *flat.shape[1:]))
    for i, n in enumerate(lengths):
        out[i, :n] = flat[bounds[i]:bounds[i + 1]]
    return out


def _action_features(a: np.ndarray, n_act: int, discrete: bool) -> np.ndarray:
    """The actions as the starts compare them: one-hot (discrete) or standardised per dimension (continuous)."""
    return np.eye(n_act)[a] if discrete else (a - a.mean(0)) / (a.std(0) + 1e-6)


def _ordered_pieces(feat: np.ndarray, k: int, max_cuts: int = 1000) -> np.ndarray:
    """Codes 0, 1, ..., k - 1 of the cut of one demonstration's (T, D) action features into k consecutive pieces
    with the least summed squared deviation from each piece's mean (exact, by dynamic programming over the cuts).
    Longer demonstrations are cut only at every ceil(T / `max_cuts`)-th step, which keeps the DP's (cuts x cuts)
    table small."""
    n = len(feat)
    at = np.unique(np.r_[np.arange(0, n, math.ceil(n / max_cuts)), n])  # where a piece may begin or end
    s1 = np.r_[np.zeros((1, feat.shape[1])), np.cumsum(feat, 0)][at]
    s2 = np.r_[0.0, np.cumsum((feat ** 2).sum(1))][at]
    m_at = len(at)
    k = min(k, m_at - 1)
    i, j = np.triu_indices(m_at, 1)
    cost = np.full((m_at, m_at), np.inf)  # cost[i, j]: the piece of steps at[i] .. at[j] - 1
    cost[i, j] = s2[j] - s2[i] - ((s1[j] - s1[i]) ** 2).sum(1) / (at[j] - at[i])
    best = cost[0].copy()  # best[j]: steps 0 .. at[j] - 1 in m pieces
    cuts = np.zeros((k, m_at), np.int64)
    for m in range(1, k):
        total = best[:, None] + cost
        cuts[m] = total.argmin(0)
        best = total.min(0)
    codes = np.empty(n, np.int64)
    end = m_at - 1
    for m in range(k - 1, -1, -1):
        begin = cuts[m, end] if m > 0 else 0
        codes[at[begin]:at[end]] = m
        end = begin
    return codes
