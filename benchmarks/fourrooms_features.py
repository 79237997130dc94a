"""Four Rooms: what the sub-task policies see, and whether the hard-EM start then finds the next corridor (issue 14,
item 5; docs/experiments.md, section Four Rooms).

    python benchmarks/fourrooms_features.py > benchmarks/results/fourrooms_features.txt

On the shipped demonstrations (label: the next corridor or the apple), per feature set, ridge and K: the start's
accuracy, NMI and switches per episode (seed 0), its description length and the oracle labels' under the same
model. Feature sets: `full`, the 52-dim observation (agent and apple one-hot); `agent`, the agent's one-hot cells
only (a policy per code is then a fixed field over the cells, as "go to corridor c" is); `agent+sign`, the agent's
cells and the signs of the apple's displacement from it, so that one linear policy can head for the apple.

Second part, `--room-visits`: a prior from the map instead of the search over switch points. Each demonstration is
cut where the agent steps onto a corridor cell (a room visit per piece, about 2 per episode), every piece takes one
code, and hard EM assigns pieces to codes (the sum of the piece's action log-likelihoods under each code's linear
policy, then the refit). The start is k-means of the state each piece ends in (the next observation of its last
step): a sub-task as the subgoal it reaches, the corridor cell for a corridor piece, the apple for the last one.
Per feature set and ridge (K = 5, seeds 0 1 2 of the k-means starts): accuracy, NMI, the pieces' description
length and the oracle labels', and seed 0's confusion matrix (rows: labels 0-3 the corridors, 4 the apple).
It also draws the fields of K = 4 codes (agent cells, ridge 0.01, seed 0: what `scripts/fourrooms_room_visits.sh`
starts the VAE from), each code's most likely action per cell, into
`benchmarks/results/figures/fourrooms_room_visit_codes.png`.
"""

from __future__ import annotations

import dataclasses
import sys
from pathlib import Path

import numpy as np

from digail.algos.segment_init import (
    _design,
    _LinearPolicies,
    hard_em_from,
    hard_em_segmentation,
    piece_em_segmentation,
)
from digail.data.minari_io import load_dataset
from digail.envs.four_rooms import (
    FREE_CELLS,
    GRID_HEIGHT,
    GRID_WIDTH,
    decode_observations,
    encode_observation,
    room_visits,
)
from digail.eval.segmentation import segmentation_metrics
from digail.viz.figures import four_rooms_arrow_maps


def features(obs: np.ndarray, kind: str) -> np.ndarray:
    obs = np.asarray(obs, np.float32)
    if kind == "full":
        return obs
    cells = obs[:, :GRID_WIDTH + GRID_HEIGHT]
    if kind == "agent":
        return cells
    agent, apple = decode_observations(obs)
    sign = np.sign(apple - agent).astype(np.int64) + 1
    return np.c_[cells, np.eye(3)[sign[:, 0]], np.eye(3)[sign[:, 1]]].astype(np.float32)


def _policies(x: np.ndarray, a: np.ndarray, n: int, ridge: float, codes: np.ndarray) -> _LinearPolicies:
    policies = _LinearPolicies(5, x.shape[1], n, True, ridge)
    policies.fit(x, a, codes)
    return policies


def by_piece(ds) -> None:  # noqa: ANN001
    labels = [np.asarray(t.subtasks)[:len(t)] for t in ds.trajs]
    flat = np.concatenate(labels)
    cuts = [room_visits(np.asarray(t.obs)[:len(t)]) for t in ds.trajs]
    mixed = [len(np.unique(lab[c == p])) > 1 for c, lab in zip(cuts, labels, strict=True) for p in np.unique(c)]
    print(f"room visits: {len(mixed) / len(ds.trajs):.2f} pieces per episode; the label changes inside a piece on "
          f"{np.mean(mixed):.3f} of them")
    for kind in ("full", "agent", "agent+sign"):
        trajs = [dataclasses.replace(t, obs=features(t.obs, kind)) for t in ds.trajs]
        for ridge in (1.0, 0.01, 0.003):
            x, a, n, _, _ = _design(trajs, True)
            oracle_cost = -float(_policies(x, a, n, ridge, flat).loglik(x, a)[np.arange(len(flat)), flat].sum())
            # the doors of a pair (0 and 2, 1 and 3) lead out of disjoint rooms: one code each pair, the apple a third
            paired = np.array([0, 1, 0, 1, 2])[flat]
            paired_cost = -float(_policies(x, a, n, ridge, paired).loglik(x, a)[np.arange(len(flat)), paired].sum())
            rows, confusion = [], None
            for seed in (0, 1, 2):
                seg = piece_em_segmentation(trajs, cuts, 5, True, seed=seed, ridge=ridge)
                codes = np.concatenate(seg)
                cost = -float(_policies(x, a, n, ridge, codes).loglik(x, a)[np.arange(len(codes)), codes].sum())
                m = segmentation_metrics(seg, labels)
                rows.append(f"{m['accuracy']:.3f} / {m['nmi']:.3f} ({cost:.1f} nats)")
                if seed == 0:
                    confusion = np.zeros((5, 5), np.int64)
                    np.add.at(confusion, (flat, codes), 1)
            print(f"pieces {kind:10s} ridge {ridge:<5} K = 5, accuracy / NMI, seeds 0 1 2: {';  '.join(rows)}; "
                  f"the oracle {oracle_cost:.1f} nats, with the pairs of doors merged {paired_cost:.1f}; "
                  f"seed 0 labels x codes {confusion.tolist()}", flush=True)


def field_figure(ds, path: Path) -> None:  # noqa: ANN001
    """The most likely action of each code's linear policy in every free cell (K = 4, agent cells, ridge 0.01)."""
    trajs = [dataclasses.replace(t, obs=features(t.obs, "agent")) for t in ds.trajs]
    cuts = [room_visits(np.asarray(t.obs)[:len(t)]) for t in ds.trajs]
    codes = np.concatenate(piece_em_segmentation(trajs, cuts, 4, True, seed=0, ridge=0.01))
    x, a, n, mean, std = _design(trajs, True)
    policies = _LinearPolicies(4, x.shape[1], n, True, 0.01)
    policies.fit(x, a, codes)
    cells = np.array(FREE_CELLS)
    obs = np.stack([encode_observation(tuple(c), (1, 1)) for c in cells])[:, :GRID_WIDTH + GRID_HEIGHT]
    xc = np.c_[(obs - mean) / std, np.ones(len(cells))]
    actions = np.einsum("td,kda->kta", xc, policies.w).argmax(-1)
    four_rooms_arrow_maps(cells, actions, path, title="Four Rooms: the room-visit start's linear policy per code "
                          "(agent cells only)")
    print(f"wrote {path}")


def main() -> None:
    ds = load_dataset("digail/fourrooms/expert-v0")
    if "--room-visits" in sys.argv[1:]:
        by_piece(ds)
        field_figure(ds, Path(__file__).resolve().parent / "results" / "figures" / "fourrooms_room_visit_codes.png")
        return
    labels = [np.asarray(t.subtasks)[:len(t)] for t in ds.trajs]
    for kind in ("full", "agent", "agent+sign"):
        trajs = [dataclasses.replace(t, obs=features(t.obs, kind)) for t in ds.trajs]
        for ridge in (1.0, 0.01):
            oracle, _ = hard_em_from(trajs, labels, 5, True, rounds=0, ridge=ridge)
            for k in (4, 5):
                seg = hard_em_segmentation(trajs, k, True, seed=0, ridge=ridge)
                cost, _ = hard_em_from(trajs, seg, k, True, rounds=0, ridge=ridge)
                m = segmentation_metrics(seg, labels)
                print(f"{kind:10s} ridge {ridge:<5} K = {k}: accuracy {m['accuracy']:.3f}  NMI {m['nmi']:.3f}  "
                      f"{m['switches_per_episode']:.2f} switches/episode (truth {m['true_switches_per_episode']:.2f})  "
                      f"{cost:8.1f} nats, the oracle {oracle:8.1f}", flush=True)


if __name__ == "__main__":
    main()
