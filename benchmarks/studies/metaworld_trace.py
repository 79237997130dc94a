"""Where the segmentation benchmark's Meta-World codes depart from the expert's phases: per phase, the codes its steps
took, and per code, the phases it covers.

    python benchmarks/studies/metaworld_trace.py runs/segbench \
        > benchmarks/studies/results/metaworld_segmentation_trace.txt

reads the benchmark's seed-0 runs (`RUNS/metaworld-<task>_s0`, made by `python benchmarks/segmentation.py --tasks
metaworld-... --runs RUNS`) and the labelled data beside them (`RUNS/datasets/segbench-metaworld-<task>`, or
`--data`). A phase whose steps go mostly to a code that also holds most of another phase's steps is merged with it;
a phase split over two codes that each hold more than a quarter of its steps is split.
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np

from digail.data.minari_io import load_dataset

TASKS = ("pick-place", "assembly", "stick-pull", "shelf-place", "basketball", "disassemble", "peg-insert-side",
         "box-close", "hammer")


def trace(run: Path, data: Path) -> list[str]:
    trajs = load_dataset(data).trajs
    stored = np.load(run / "codes.npz", allow_pickle=False)
    codes = np.concatenate([stored[f"episode_{i:05d}"][:len(t)] for i, t in enumerate(trajs)])
    labels = np.concatenate([np.asarray(t.subtasks)[:len(t)] for t in trajs])
    k, n = int(codes.max()) + 1, int(labels.max()) + 1
    counts = np.zeros((n, k), dtype=int)
    np.add.at(counts, (labels, codes), 1)
    lines = []
    majority = counts.argmax(1)
    for p in range(n):
        share = counts[p] / max(counts[p].sum(), 1)
        big = [f"code {c} {share[c]:.2f}" for c in np.argsort(-share) if share[c] > 0.1]
        merged = [int(q) for q in range(n) if q != p and majority[q] == majority[p]]
        split = int((share > 0.25).sum()) > 1
        note = ("merged with phase " + ", ".join(map(str, merged)) if merged else "") + \
               ("; " if merged and split else "") + ("split" if split else "")
        lines.append(f"  phase {p} ({counts[p].sum():5d} steps): {', '.join(big)}{'  <- ' + note if note else ''}")
    return lines


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("runs", type=Path)
    parser.add_argument("--data", type=Path, default=None)
    args = parser.parse_args()
    data = args.data or args.runs / "datasets"
    for task in TASKS:
        run = args.runs / f"metaworld-{task}_s0"
        if not (run / "codes.npz").is_file():
            continue
        print(f"{task}:")
        print("\n".join(trace(run, data / f"segbench-metaworld-{task}")))


if __name__ == "__main__":
    main()
