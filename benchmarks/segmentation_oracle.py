"""Is a segmentation miss the hard-EM start's search or its criterion? (issue 14, docs/experiments.md)

    python benchmarks/segmentation_oracle.py grid-six fetch

Per task: the description length (nats) and accuracy of the start `digail pretrain` uses (seed 0), of the oracle
labels themselves under the same switching-linear-policy model, and of hard EM started from the oracle labels.
When the oracle costs more than what the search found, more starts cannot help: the model ranks the truth lower.
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from segmentation import task_data  # noqa: E402

from digail.algos.segment_init import hard_em_from, hard_em_segmentation  # noqa: E402
from digail.data.minari_io import load_dataset  # noqa: E402
from digail.eval.segmentation import segmentation_metrics  # noqa: E402
from digail.nets.policy import ActionSpec  # noqa: E402


def main(names: list[str]) -> None:
    for name in names:
        demos, codes, _, _ = task_data(name, Path("runs/segbench/datasets"))
        ds = load_dataset(demos)
        discrete = ActionSpec.from_space(ds.action_space).discrete
        labels = [np.asarray(t.subtasks)[:len(t)] for t in ds.trajs]
        found = hard_em_segmentation(ds.trajs, codes, discrete, seed=0)
        rows = {"start (seed 0)": hard_em_from(ds.trajs, found, codes, discrete, rounds=0),
                "oracle labels": hard_em_from(ds.trajs, labels, codes, discrete, rounds=0),
                "hard EM from the oracle": hard_em_from(ds.trajs, labels, codes, discrete)}
        for what, (cost, seg) in rows.items():
            m = segmentation_metrics(seg, labels)
            print(f"{name:10s} {what:24s} {cost:12.1f} nats  accuracy {m['accuracy']:.3f}  "
                  f"{m['switches_per_episode']:.2f} switches/episode", flush=True)


if __name__ == "__main__":
    main(sys.argv[1:] or ["grid-six", "fetch"])
