"""One segmentation across Meta-World tasks: a VAE pre-trained on the demonstrations of several tasks together.

    python benchmarks/metaworld_shared.py  # -> results/metaworld/metaworld_shared.json, figures/metaworld_shared.png
    python benchmarks/metaworld_shared.py --seeds 0 --out runs/shared.json

Eight tasks whose experts reach above an object, descend onto it, and then lift it, carry it or both (pick-place,
shelf-place, basketball, box-close, pick-out-of-hole, disassemble, peg-insert-side, coffee-pull): their experts'
phases (`info["subtask"]`, runs under `MIN_SEGMENT` steps merged) are mapped to five phase kinds by reading each
expert's `_desired_pos` (`KINDS`). The shipped demonstrations of these tasks (50 each) are written into one data set
labelled with the kinds, and each seed runs what a user types, with the defaults and K = 5:

    digail pretrain --demos D --codes 5 --seed S --out R/shared_sS --preset default
    digail segment R/shared_sS

Does the same code mean the same phase kind in every task? Measured per task: the accuracy under the one code ->
kind matching of all tasks together (`shared`, one-to-one), against the accuracy under the task's own best matching
(`own`, an upper bound for a code that means something different in each task), and the NMI; with `--codes` above
the five kinds, `shared_many_to_one` maps each code to the kind most of its steps carry in all tasks together (a
kind may take several codes; a code still means one kind everywhere). The figure shows each task's code x kind
counts of the first seed.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import shlex
import sys
from pathlib import Path
from typing import Any

import numpy as np

HERE = Path(__file__).resolve().parent

KIND_NAMES = ("reach above", "descend", "close the gripper", "lift", "carry to the goal")
KINDS: dict[str, tuple[int, ...]] = {
    # move above the puck, descend onto it, wait for the fingers to close, move to the goal
    "pick-place": (0, 1, 2, 4),
    # above the block (30 cm up), down onto it, to the shelf's x at 30 cm height, up to 30 cm, forward to the goal
    "shelf-place": (0, 1, 3, 3, 4),
    # above the ball (30 cm up), down onto it, up to the hoop's height, to the hoop
    "basketball": (0, 1, 3, 4),
    # above the lid, down onto it, up to the box's height, over the box
    "box-close": (0, 1, 3, 4),
    # above the puck, down into the hole, up to the goal's height, to the goal
    "pick-out-of-hole": (0, 1, 3, 4),
    # above the wrench, down onto it, straight up off the peg
    "disassemble": (0, 1, 3),
    # above the peg (30 cm up), down onto it, to the hole's line, into the hole
    "peg-insert-side": (0, 1, 4, 4),
    # above the mug, down to it, pull it to the target
    "coffee-pull": (0, 1, 4),
}
"""each task's expert phases (by index) -> phase kind (index into KIND_NAMES)"""


def shared_dataset(folder: Path) -> tuple[Path, list[str]]:
    """Write the three tasks' shipped demonstrations, labelled with the phase kinds, into `folder` (once); returns the
    folder and each episode's task."""
    from digail.data.minari_io import load_dataset
    from digail.data.minari_write import write_dataset
    from digail.envs.metaworld import MIN_SEGMENT, merge_short_runs

    trajs, tasks = [], []
    for task, kinds in KINDS.items():
        for t in load_dataset(f"digail/metaworld-{task}/expert-v0").trajs:
            phases = merge_short_runs(np.asarray(t.subtasks), MIN_SEGMENT)
            if phases.max() >= len(kinds):  # a new Meta-World version's expert with another phase
                raise SystemExit(f"{task}: phase {phases.max()} has no kind in KINDS")
            trajs.append(dataclasses.replace(t, subtasks=np.asarray(kinds, dtype=np.int64)[phases]))
            tasks.append(task)
    if not (folder / "data" / "metadata.json").is_file():
        write_dataset(trajs, folder, "metaworld/pick-place-v3", "segbench/metaworld-shared-v0",
                      description=f"Meta-World {', '.join(KINDS)}, 50 demonstrations each, labelled with the phase "
                                  "kinds of benchmarks/metaworld_shared.py")
    return folder, tasks


def one_to_one(codes: np.ndarray, labels: np.ndarray, k: int, n: int) -> dict[int, int]:
    """The code -> label matching (one-to-one, Hungarian) with the most steps agreeing."""
    from scipy.optimize import linear_sum_assignment

    counts = np.zeros((k, n))
    np.add.at(counts, (codes, labels), 1)
    rows, cols = linear_sum_assignment(-counts)
    return {int(r): int(c) for r, c in zip(rows, cols, strict=True)}


def many_to_one(codes: np.ndarray, labels: np.ndarray, k: int, n: int) -> dict[int, int]:
    """Each code -> the label most of its steps carry (several codes may share a kind; with more codes than kinds
    every code still means one kind in every task)."""
    counts = np.zeros((k, n))
    np.add.at(counts, (codes, labels), 1)
    return {c: int(np.argmax(counts[c])) for c in range(k) if counts[c].sum()}


def majority_kinds(mapping: dict[int, int], codes: np.ndarray) -> np.ndarray:
    """Each step's kind under `mapping` (-1 for a code it leaves out: one-to-one with more codes than kinds)."""
    return np.array([mapping.get(int(c), -1) for c in codes])


def measure(run: Path, demos: Path, tasks: list[str], k: int) -> dict[str, Any]:
    from sklearn.metrics import normalized_mutual_info_score

    from digail.data.minari_io import load_dataset

    trajs = load_dataset(demos).trajs
    codes_file = np.load(run / "codes.npz", allow_pickle=False)
    codes = [np.asarray(codes_file[f"episode_{i:05d}"][:len(t)]) for i, t in enumerate(trajs)]
    labels = [np.asarray(t.subtasks)[:len(t)] for t in trajs]
    every_c, every_l = np.concatenate(codes), np.concatenate(labels)
    shared = one_to_one(every_c, every_l, k, len(KIND_NAMES))
    majority = many_to_one(every_c, every_l, k, len(KIND_NAMES))
    out: dict[str, Any] = {"mapping": {str(c): KIND_NAMES[v] for c, v in shared.items()},
                           "accuracy": float(np.mean(majority_kinds(shared, every_c) == every_l)),
                           "mapping_many_to_one": {str(c): KIND_NAMES[v] for c, v in majority.items()},
                           "accuracy_many_to_one": float(np.mean(majority_kinds(majority, every_c) == every_l)),
                           "tasks": {}}
    for task in KINDS:
        idx = [i for i, t in enumerate(tasks) if t == task]
        c, lab = np.concatenate([codes[i] for i in idx]), np.concatenate([labels[i] for i in idx])
        own = one_to_one(c, lab, k, len(KIND_NAMES))
        counts = np.zeros((k, len(KIND_NAMES)), dtype=int)
        np.add.at(counts, (c, lab), 1)
        out["tasks"][task] = {"shared": float(np.mean(majority_kinds(shared, c) == lab)),
                              "shared_many_to_one": float(np.mean(majority_kinds(majority, c) == lab)),
                              "own": float(np.mean(majority_kinds(own, c) == lab)),
                              "nmi": float(normalized_mutual_info_score(lab, c)), "steps": int(len(c)),
                              "counts": counts.tolist()}
    return out


def figure(result: dict[str, Any], out: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    seed = result["seeds"][0]
    cols = 4
    rows = -(-len(KINDS) // cols)
    fig, axes = plt.subplots(rows, cols, figsize=(4.2 * cols, 3.6 * rows), squeeze=False)
    for ax in axes.flat[len(KINDS):]:
        ax.axis("off")
    for ax, (task, row) in zip(axes.flat[:len(KINDS)], seed["tasks"].items(), strict=True):
        counts = np.asarray(row["counts"], dtype=float)
        share = counts / np.maximum(counts.sum(0, keepdims=True), 1)  # per kind: where its steps went
        ax.imshow(share, cmap="Blues", vmin=0, vmax=1)
        for (i, j), v in np.ndenumerate(counts):
            if v:
                ax.text(j, i, f"{int(v)}", ha="center", va="center", fontsize=7,
                        color="white" if share[i, j] > 0.6 else "black")
        ax.set_xticks(range(len(KIND_NAMES)), [n.replace(" ", "\n", 1) for n in KIND_NAMES], fontsize=7)
        ax.set_yticks(range(counts.shape[0]), [f"code {i} ({seed['mapping'].get(str(i), '-')})"
                                               for i in range(counts.shape[0])], fontsize=7)
        ax.set_title(f"{task}: shared matching {row['shared']:.2f}, own {row['own']:.2f}", fontsize=8)
    fig.suptitle(f"One VAE (K = 5, defaults, seed {seed['seed']}) on {len(KINDS)} Meta-World tasks, shared matching "
                 f"{seed['accuracy']:.2f}: steps per code and the expert's phase kind (shade: share of the kind's "
                 "steps)", fontsize=9)
    fig.tight_layout()
    out.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(out, dpi=110)
    print(f"wrote {out}")


def main(argv: list[str] | None = None) -> None:
    from digail.cli import main as digail

    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seeds", nargs="+", type=int, default=[0, 1, 2])
    parser.add_argument("--codes", type=int, default=len(KIND_NAMES))
    parser.add_argument("--runs", type=Path, default=Path("runs/metaworld_shared"))
    parser.add_argument("--out", type=Path, default=HERE / "results" / "metaworld" / "metaworld_shared.json")
    parser.add_argument("--figure", type=Path, default=HERE / "results" / "figures" / "metaworld_shared.png")
    args = parser.parse_args(argv)
    demos, tasks = shared_dataset(args.runs / f"data_{len(KINDS)}_tasks")  # relative: the record stays portable
    result: dict[str, Any] = {"command": "python benchmarks/metaworld_shared.py "
                                         + shlex.join(sys.argv[1:] if argv is None else argv),
                              "kinds": list(KIND_NAMES), "phase_kinds": {t: list(k) for t, k in KINDS.items()},
                              "seeds": []}
    for seed in args.seeds:
        run = args.runs / f"shared_k{args.codes}_s{seed}"
        cmd = ["pretrain", "--demos", str(demos), "--codes", str(args.codes), "--seed", str(seed), "--out", str(run),
               "--force", "--preset", "default"]
        print("$ digail " + shlex.join(cmd), flush=True)
        if (run / "codes.npz").is_file():  # a finished run is measured again, not retrained
            print(f"{run} is segmented already; measuring it")
        elif digail(cmd) != 0 or digail(["segment", str(run)]) != 0:
            raise SystemExit(f"digail pretrain / segment failed on seed {seed}")
        row = {"seed": seed, "command": "digail " + shlex.join(cmd), **measure(run, demos, tasks, args.codes)}
        result["seeds"].append(row)
        print(f"== seed {seed}: accuracy {row['accuracy']:.3f} (many-to-one {row['accuracy_many_to_one']:.3f}) "
              + "  ".join(
            f"{t} shared {r['shared']:.3f} own {r['own']:.3f}" for t, r in row["tasks"].items()), flush=True)
        args.out.parent.mkdir(parents=True, exist_ok=True)
        args.out.write_text(json.dumps(result, indent=1) + "\n")
    figure(result, args.figure)


if __name__ == "__main__":
    main()
