"""Is a segmentation miss the hard-EM start's search, its criterion, or the labels themselves? (issue 14,
docs/experiments.md)

    python benchmarks/segmentation_oracle.py grid-six fetch four-rooms > benchmarks/results/segmentation_oracle.txt
    python benchmarks/segmentation_oracle.py --split-merge grid-six      # also a split-merge search from the start

Per task:

- the description length (nats) and accuracy of the start `digail pretrain` uses (seed 0), of the oracle labels
  themselves under the same switching-linear-policy model, and of hard EM started from the oracle labels. When
  the oracle costs more than what the search found, more starts cannot help: the model ranks the truth lower;
- the ceilings the labels set on one-to-one accuracy. With K codes for L > K labels, at least the L - K smallest
  labels go unmatched. And per pair of labels, what merging them changes in the oracle's description length: a
  pair whose merge costs (almost) nothing is a pair the actions do not tell apart, and a segmentation that merges
  it scores at most 1 - (the smaller label's share of the steps);
- with `--split-merge`, a wider search from the start: free one code (its steps take the code before them),
  split another by 2-means of its (action, state) pairs, rerun hard EM, keep any improvement, until no pair of
  codes improves. It tells whether a cheaper segmentation than the start exists and how accurate it is.
"""

from __future__ import annotations

import itertools
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from segmentation import task_data  # noqa: E402

from digail.algos.segment_init import _action_features, _design, _kmeans, hard_em_from, hard_em_segmentation  # noqa: E402
from digail.data.minari_io import load_dataset  # noqa: E402
from digail.eval.segmentation import segmentation_metrics  # noqa: E402
from digail.nets.policy import ActionSpec  # noqa: E402


def split_merge(trajs: list, codes: int, discrete: bool, seg: list[np.ndarray], cost: float
                ) -> tuple[float, list[np.ndarray]]:
    """The search of the module docstring, from the segmentation `seg` of description length `cost`."""
    rng = np.random.default_rng(0)
    x, a, n_act, _, _ = _design(trajs, discrete)
    feat = np.c_[_action_features(a, n_act, discrete), 0.5 * x[:, :-1]]  # what the k-means start clusters
    bounds = np.cumsum([0, *[len(t) for t in trajs]])
    improved = True
    while improved:
        improved = False
        flat = np.concatenate(seg)
        for split, free in itertools.permutations(range(codes), 2):
            new = flat.copy()
            for i in range(len(trajs)):
                c = new[bounds[i]:bounds[i + 1]]
                keep = np.flatnonzero(c != free)
                c[:] = c[keep[np.maximum(np.searchsorted(keep, np.arange(len(c)), "right") - 1, 0)]] if len(keep) \
                    else split
            sel = np.flatnonzero(new == split)
            if len(sel) < 2:
                continue
            new[sel[_kmeans(feat[sel], 2, rng) == 1]] = free
            c2, seg2 = hard_em_from(trajs, [new[bounds[i]:bounds[i + 1]] for i in range(len(trajs))], codes,
                                    discrete)
            if c2 < cost - 1e-6:
                cost, seg, improved = c2, seg2, True
                break
    return cost, seg


def main(names: list[str]) -> None:
    search = "--split-merge" in names
    names = [n for n in names if n != "--split-merge"] or ["grid-six", "fetch", "four-rooms"]
    for name in names:
        demos, codes, _, _ = task_data(name, Path("runs/segbench/datasets"))
        ds = load_dataset(demos)
        discrete = ActionSpec.from_space(ds.action_space).discrete
        labels = [np.asarray(t.subtasks)[:len(t)] for t in ds.trajs]
        n_labels = int(max(int(c.max()) for c in labels)) + 1
        found = hard_em_segmentation(ds.trajs, codes, discrete, seed=0)
        rows = {"start (seed 0)": hard_em_from(ds.trajs, found, codes, discrete, rounds=0),
                "oracle labels": hard_em_from(ds.trajs, labels, n_labels, discrete, rounds=0),
                "hard EM from the oracle": hard_em_from(ds.trajs, labels, n_labels, discrete)}
        if search:
            rows["split-merge search from the start"] = split_merge(ds.trajs, codes, discrete, found,
                                                                    rows["start (seed 0)"][0])
        for what, (cost, seg) in rows.items():
            m = segmentation_metrics(seg, labels)
            print(f"{name:10s} {what:34s} {cost:12.1f} nats  accuracy {m['accuracy']:.3f}  "
                  f"{m['switches_per_episode']:.2f} switches/episode", flush=True)
        share = np.bincount(np.concatenate(labels), minlength=n_labels) / sum(len(c) for c in labels)
        print(f"{name:10s} label shares {' '.join(f'{s:.3f}' for s in share)}; K = {codes}, "
              f"{n_labels} labels: one-to-one accuracy <= {1 - np.sort(share)[:max(n_labels - codes, 0)].sum():.3f}")
        oracle_cost = rows["oracle labels"][0]
        for i, j in itertools.combinations(range(n_labels), 2):
            # label j becomes label i, the labels above j move down by one
            merged = [np.where(c == j, i, c) - (c > j) for c in labels]
            cost, _ = hard_em_from(ds.trajs, merged, n_labels - 1, discrete, rounds=0)
            print(f"{name:10s} merge labels {i} + {j}: {cost - oracle_cost:+10.1f} nats; a segmentation that merges "
                  f"them scores <= {1 - min(share[i], share[j]):.3f}", flush=True)


if __name__ == "__main__":
    main(sys.argv[1:])
