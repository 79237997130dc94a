"""End to end on data in robomimic's layout: the shipped Fetch pick-and-place demonstrations written as a
robomimic file, segmented by digail, the segmentation exported as MimicGen sub-task termination signals and
scored against the expert's own phases.

    python benchmarks/robomimic_fetch.py write --out runs/robomimic_fetch          # fetch.hdf5 + oracle.npz
    digail import runs/robomimic_fetch/fetch.hdf5 --out runs/robomimic_fetch/demos
    digail pretrain --demos runs/robomimic_fetch/demos --codes 2 --seed 0 --preset default \\
        --out runs/robomimic_fetch/vae
    digail segment runs/robomimic_fetch/vae --demos runs/robomimic_fetch/fetch.hdf5 --export robomimic \\
        --names pick place --out runs/robomimic_fetch/fetch_annotated.hdf5
    python benchmarks/robomimic_fetch.py score runs/robomimic_fetch/fetch_annotated.hdf5 \\
        runs/robomimic_fetch/oracle.npz --figure docs/figures/robomimic_fetch.png

`write` lays the 500 demonstrations out as robosuite's demonstrations are after robomimic's conversion:
`data/demo_<n>/obs/<key>` with robosuite-style key names for the 28 numbers of digail's Fetch observation,
`next_obs/<key>`, `actions`, `rewards`, `dones` (1 on the last step), `data.attrs["env_args"]` and
`mask/train`, `mask/valid`. It holds no sub-task annotation: the expert's phases go to `oracle.npz` beside it,
merged into pick (reach, grasp) and place (carry, place), the two sub-tasks a MimicGen task spec would name.

`score` reads the exported signals back with h5py alone, as MimicGen's source-dataset parser does (the first
0 -> 1 step of a signal ends its sub-task), turns them into per-step sub-task indices (how many signals have
turned 1) and scores them against the oracle: accuracy after the best code-to-label matching and boundary F1
within +-2 steps (`digail.eval.segmentation.segmentation_metrics`).
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import h5py
import numpy as np

from digail.data.minari_io import load_dataset
from digail.eval.segmentation import merge_labels, segmentation_metrics

DATASET = "digail/fetchpickandplace/expert-v0"
OBS_KEYS = {  # robosuite-style names for the slices of digail's Fetch observation (digail.envs.fetch)
    "robot0_eef_pos": [slice(0, 3)],
    "object": [slice(3, 9), slice(11, 20)],  # position, position relative to the gripper, rotation, velocities
    "robot0_gripper_qpos": [slice(9, 11)],
    "robot0_eef_vel_lin": [slice(20, 23)],
    "robot0_gripper_qvel": [slice(23, 25)],
    "goal_pos": [slice(25, 28)],
}
PICK_PLACE = (0, 0, 1, 1)
"""the four phases (reach, grasp, carry, place) merged into pick and place"""


def write(out: Path) -> None:
    ds = load_dataset(DATASET)
    out.mkdir(parents=True, exist_ok=True)
    oracle = {}
    with h5py.File(out / "fetch.hdf5", "w") as f:
        data = f.create_group("data")
        for i, traj in enumerate(ds.trajs):
            demo = data.create_group(f"demo_{i}")
            obs = traj.obs.astype(np.float64)
            for key, parts in OBS_KEYS.items():
                value = np.concatenate([obs[:, s] for s in parts], axis=1)
                demo.create_dataset(f"obs/{key}", data=value[:-1])
                demo.create_dataset(f"next_obs/{key}", data=value[1:])
            demo.create_dataset("actions", data=traj.acts.astype(np.float64))
            demo.create_dataset("rewards", data=np.zeros(len(traj)) if traj.rews is None else traj.rews)
            demo.create_dataset("dones", data=(np.arange(len(traj)) == len(traj) - 1).astype(np.int64))
            demo.attrs["num_samples"] = len(traj)
            assert traj.subtasks is not None
            oracle[f"demo_{i}"] = merge_labels(traj.subtasks, PICK_PLACE)
        data.attrs["total"] = sum(len(t) for t in ds.trajs)
        data.attrs["env_args"] = json.dumps({"env_name": "FetchPickAndPlace-v4", "type": 4,
                                             "env_kwargs": {"source": DATASET}})
        names = [f"demo_{i}" for i in range(len(ds.trajs))]
        split = int(0.9 * len(names))
        f.create_dataset("mask/train", data=np.array(names[:split], dtype="S"))
        f.create_dataset("mask/valid", data=np.array(names[split:], dtype="S"))
    np.savez_compressed(out / "oracle.npz", **oracle)
    print(f"wrote {out / 'fetch.hdf5'} ({len(ds.trajs)} demonstrations) and {out / 'oracle.npz'}")


def signals_to_labels(demo: h5py.Group) -> np.ndarray:
    """Per step, how many of the demonstration's termination signals have turned 1 (MimicGen's reading)."""
    group = demo["datagen_info/subtask_term_signals"]
    ended = [np.maximum.accumulate(np.asarray(group[name][()]) != 0) for name in group]
    return np.sum(ended, axis=0).astype(np.int64)


def score(exported: Path, oracle_file: Path, figure: Path | None) -> dict[str, float]:
    oracle = np.load(oracle_file)
    pred, true = [], []
    with h5py.File(exported, "r") as f:
        for key in sorted(f["data"], key=lambda k: int(k.split("_")[1])):
            steps = int(f["data"][key]["actions"].shape[0])
            pred.append(signals_to_labels(f["data"][key]))
            true.append(oracle[key][:steps])
    metrics = segmentation_metrics(pred, true)
    result = {k: metrics[k] for k in ("accuracy", "boundary_f1", "boundary_precision", "boundary_recall",
                                      "switches_per_episode", "true_switches_per_episode", "episodes", "steps")}
    print(json.dumps(result, indent=1))
    if figure is not None:
        plot(figure, pred, true)
    return result


def plot(path: Path, pred: list[np.ndarray], true: list[np.ndarray], episodes: int = 8) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(8, 0.5 * episodes + 1.2))
    for i in range(episodes):
        y = episodes - 1 - i
        for seq, offset in ((pred[i], 0.05), (true[i], -0.35)):  # exported above, oracle below
            colours = ["tab:blue" if v == 0 else "tab:orange" for v in seq]
            ax.bar(np.arange(len(seq)), 0.3, bottom=y + offset, width=1.0, color=colours, linewidth=0)
        for b in np.flatnonzero(np.diff(true[i])) + 1:
            ax.plot([b - 0.5, b - 0.5], [y - 0.35, y + 0.35], color="black", linewidth=1.2)
    ax.set_yticks(range(episodes), [f"demo_{episodes - 1 - i}" for i in range(episodes)])
    ax.set_xlabel("step (upper strip: exported MimicGen signals; lower strip: oracle; line: oracle boundary)")
    ax.set_title("Fetch pick (blue) / place (orange): digail's exported sub-tasks against the expert's phases")
    fig.tight_layout()
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=110)
    plt.close(fig)
    print(f"wrote {path}")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    sub = parser.add_subparsers(dest="command", required=True)
    w = sub.add_parser("write", help="write the Fetch demonstrations as a robomimic file and the oracle beside it")
    w.add_argument("--out", type=Path, required=True)
    s = sub.add_parser("score", help="score an exported robomimic file's signals against the oracle")
    s.add_argument("exported", type=Path)
    s.add_argument("oracle", type=Path)
    s.add_argument("--figure", type=Path)
    args = parser.parse_args()
    if args.command == "write":
        write(args.out)
    else:
        score(args.exported, args.oracle, args.figure)


if __name__ == "__main__":
    main()
