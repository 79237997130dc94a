"""Four Rooms: what the sub-task policies see, and whether the hard-EM start then finds the next corridor (issue 14,
item 5; docs/experiments.md, section Four Rooms).

    python benchmarks/fourrooms_features.py > benchmarks/results/fourrooms_features.txt

On the shipped demonstrations (label: the next corridor or the apple), per feature set, ridge and K: the start's
accuracy, NMI and switches per episode (seed 0), its description length and the oracle labels' under the same
model. Feature sets: `full`, the 52-dim observation (agent and apple one-hot); `agent`, the agent's one-hot cells
only (a policy per code is then a fixed field over the cells, as "go to corridor c" is); `agent+sign`, the agent's
cells and the signs of the apple's displacement from it, so that one linear policy can head for the apple.
"""

from __future__ import annotations

import dataclasses

import numpy as np

from digail.algos.segment_init import hard_em_from, hard_em_segmentation
from digail.data.minari_io import load_dataset
from digail.envs.four_rooms import GRID_HEIGHT, GRID_WIDTH, decode_observations
from digail.eval.segmentation import segmentation_metrics


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


def main() -> None:
    ds = load_dataset("digail/fourrooms/expert-v0")
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
