"""digail's exported MimicGen sub-task boundaries on robosuite demonstrations, scored against MimicGen's own
signals computed from the simulator (scripts/robosuite_producer/produce.py writes both files).

    python benchmarks/robosuite_mimicgen.py score EXPORTED ORACLE --run RUN --oracle-signal grasp \\
        --figure FIGURE --json JSON --command "..." --command "..."

For each demonstration:

- MimicGen's boundary of a sub-task is where its `parse_source_dataset` ends it: one step after the first 0 -> 1
  of the oracle signal (the signal is computed at every recorded state as MimicGen's `prepare_src_dataset.py` does).
- digail's boundaries are read back from the export the same way: each exported signal's first 0 -> 1 step, the
  signals taken in the order of those steps (the export's plan gives every demonstration the same number and
  order). The export is also run through MimicGen's parsing rule (rewritten in `mimicgen_ends`, the rule of
  NVlabs/mimicgen at commit 72bd767, zero offsets) to check that it is accepted.
- With more exported boundaries than MimicGen's (K larger than MimicGen's sub-task count), one exported boundary is
  chosen for the dataset, not per demonstration: the one whose median absolute error is the smallest. The final
  sub-task ends with the demonstration for both, so only the signalled sub-tasks are scored.

The error is digail's boundary minus MimicGen's, in steps; the targets are a median absolute error <= 5 steps and
>= 90 % of the demonstrations within 10 steps. The figure shows, per demonstration, the oracle signal (upper strip)
above digail's codes (lower strip), with MimicGen's boundary (black) and the exported one (red, dashed).
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import h5py
import numpy as np

SIGNALS = "datagen_info/subtask_term_signals"


def demo_order(keys: list[str]) -> list[str]:
    return sorted(keys, key=lambda k: int(k.split("_")[1]))


def first_one(signal: np.ndarray) -> int | None:
    """The step MimicGen reads as a signal's first 0 -> 1 (None without one)."""
    diffs = np.diff(np.asarray(signal).astype(np.int64))
    nz = np.flatnonzero(diffs)
    return int(nz[0]) + 1 if len(nz) else None


def mimicgen_ends(signals: dict[str, np.ndarray], spec: list[str | None], n_steps: int) -> list[int]:
    """MimicGen's parse_source_dataset rule with zero offsets: sub-task i ends one step after the first 0 -> 1 of
    its signal at or after the previous end; the last at the end. Raises AssertionError where MimicGen's does."""
    ends, prev = [], 0
    for name in spec:
        if name is None:
            end = n_steps
        else:
            diffs = signals[name][1:].astype(np.int64) - signals[name][:-1].astype(np.int64)
            first = next((int(nz) + 1 for nz in diffs.nonzero()[0] if int(nz) + 1 >= prev), None)
            assert first is not None, f"No valid subtask termination found for {name}"
            end = first + 1
        ends.append(end)
        prev = end
    for a, b in zip(ends, ends[1:], strict=False):
        assert a < b, f"sub-task ends {a} then {b}"
    return ends


def read_export(path: Path) -> tuple[list[str], dict[str, dict[str, np.ndarray]], list[str | None]]:
    """Each demonstration's exported signals (digail's, as listed in `digail_signals`) and the task spec order."""
    out, firsts = {}, {}
    with h5py.File(path, "r") as f:
        keys = demo_order([k for k in f["data"] if k.startswith("demo")])
        for key in keys:
            group = f[f"data/{key}/{SIGNALS}"]
            ours = json.loads(group.attrs["digail_signals"])
            out[key] = {n: group[n][()] for n in ours}
            firsts[key] = {n: first_one(s) for n, s in out[key].items()}
    orders = {tuple(sorted((n for n, b in fs.items() if b is not None), key=lambda n: fs[n])) for fs in
              firsts.values()}
    if len(orders) != 1:
        raise SystemExit(f"the export's demonstrations differ in sub-task order: {sorted(orders)}")
    spec: list[str | None] = [*orders.pop(), None]
    return keys, out, spec


def offsets_check(ends: list[int], n_steps: int, offsets: tuple[int, int]) -> bool:
    """MimicGen's sanity check of a demonstration's sub-task ends under the term offsets `offsets` for every
    signalled sub-task and (0, 0) for the last: end of sub-task i + its largest offset < end of sub-task i + 1 + its
    smallest offset (NVlabs/mimicgen's parse_source_dataset, rewritten)."""
    full = [*ends, n_steps]
    ranges = [offsets] * len(ends) + [(0, 0)]
    return all(full[i - 1] + ranges[i - 1][1] < full[i] + ranges[i][0] for i in range(1, len(full)))


def score(exported: Path, oracle: Path, oracle_signal: str, run: Path | None, figure: Path | None,
          json_out: Path | None, commands: list[str], gripper_dim: int | None = 6,
          offsets: tuple[int, int] = (10, 20)) -> dict:
    keys, signals, spec = read_export(exported)
    ours, truth, lengths, closes = [], [], [], []
    with h5py.File(oracle, "r") as g, h5py.File(exported, "r") as f:
        producer = json.loads(g.attrs["producer"])
        oracle_raw = {}
        for key in keys:
            n = int(f[f"data/{key}/actions"].shape[0])
            lengths.append(n)
            raw = g[f"data/{key}/{SIGNALS}/{oracle_signal}"][()]
            oracle_raw[key] = raw
            truth.append(mimicgen_ends({oracle_signal: raw}, [oracle_signal, None], n)[0])
            ours.append(mimicgen_ends(signals[key], spec, n)[:-1])  # raises where MimicGen's parser would
            if gripper_dim is not None:  # the first step the gripper is commanded closed (robosuite: +1 closes)
                closes.append(int(np.flatnonzero(f[f"data/{key}/actions"][:, gripper_dim] > 0)[0]))
    ours_arr = np.array(ours)  # (demos, exported boundaries)
    truth_arr = np.array(truth)
    errors = ours_arr - truth_arr[:, None]
    medians = np.median(np.abs(errors), axis=0) if ours_arr.shape[1] else np.array([])
    chosen = int(np.argmin(medians)) if len(medians) else None
    err = errors[:, chosen] if chosen is not None else np.full(len(keys), np.nan)
    abs_err = np.abs(err)
    result = {
        "task": producer["task"], "export": str(exported), "oracle": str(oracle), "oracle_signal": oracle_signal,
        "producer": producer, "demonstrations": len(keys), "steps": int(sum(lengths)),
        "mimicgen_spec_of_export": spec,
        "exported_boundaries_per_demo": int(ours_arr.shape[1]),
        "chosen_exported_signal": spec[chosen] if chosen is not None else None,
        "median_abs_error_of_each_exported_boundary": [float(m) for m in medians],
        "median_abs_error": float(np.median(abs_err)),
        "mean_signed_error": float(np.mean(err)),
        "within_10_steps": float(np.mean(abs_err <= 10)),
        "within_5_steps": float(np.mean(abs_err <= 5)),
        "max_abs_error": float(np.max(abs_err)),
        "target_met": bool(np.median(abs_err) <= 5 and np.mean(abs_err <= 10) >= 0.9),
        "mimicgen_parser_rule_accepts_export": True,
        "offsets": list(offsets),
        "offsets_check_passed": int(sum(offsets_check(o, n, offsets) for o, n in zip(ours, lengths, strict=True))),
        "offsets_check_passed_first_20": int(sum(offsets_check(o, n, offsets)
                                                  for o, n in list(zip(ours, lengths, strict=True))[:20])),
        "trace": None if not closes else {
            "what": "steps from the first step the gripper is commanded closed (actions[:, 6] > 0) to the first step "
                    "the oracle signal is 1, and to the first step digail's chosen exported signal is 1",
            "oracle_minus_close_command": _spread(truth_arr - 1 - np.array(closes)),
            "digail_minus_close_command": _spread(ours_arr[:, chosen] - 1 - np.array(closes))
            if chosen is not None else None},
        "per_demo": {k: {"steps": n, "mimicgen_end": int(t), "digail_ends": [int(x) for x in o],
                         "error": int(e)} for k, n, t, o, e in zip(keys, lengths, truth, ours, err, strict=True)},
        "commands": commands,
    }
    summary = {k: result[k] for k in ("task", "demonstrations", "mimicgen_spec_of_export", "chosen_exported_signal",
                                       "median_abs_error", "mean_signed_error", "within_10_steps", "max_abs_error",
                                       "target_met")}
    print(json.dumps(summary))
    if json_out is not None:
        json_out.parent.mkdir(parents=True, exist_ok=True)
        json_out.write_text(json.dumps(result, indent=1) + "\n")
    if figure is not None and run is not None:
        with np.load(run / "codes.npz") as stored:
            codes = [stored[k] for k in sorted(stored.files)]
        plot(figure, keys, oracle_raw, codes, truth, [o[chosen] if chosen is not None else None for o in ours],
             f"{producer['task']}: MimicGen's `{oracle_signal}` (upper) above digail's codes (lower)")
    return result


def _spread(values: np.ndarray) -> dict:
    return {"median": float(np.median(values)), "min": int(np.min(values)), "max": int(np.max(values)),
            "counts": {int(v): int(c) for v, c in zip(*np.unique(values, return_counts=True), strict=True)}}


def plot(path: Path, keys: list[str], oracle_raw: dict, codes: list[np.ndarray], truth: list[int],
         ours: list[int | None], title: str, episodes: int = 10) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    palette = plt.get_cmap("tab10")
    fig, ax = plt.subplots(figsize=(9, 0.55 * episodes + 1.3))
    for i in range(min(episodes, len(keys))):
        y = episodes - 1 - i
        sig = oracle_raw[keys[i]]
        ax.bar(np.arange(len(sig)), 0.3, bottom=y + 0.05, width=1.0, linewidth=0,
               color=["0.85" if v == 0 else "tab:green" for v in sig])
        c = codes[i]
        ax.bar(np.arange(len(c)), 0.3, bottom=y - 0.35, width=1.0, linewidth=0, color=[palette(int(v)) for v in c])
        # parsed ends are one step after the first 1; draw the line at the first 1 (the step the sub-task changes)
        ax.plot([truth[i] - 1.5, truth[i] - 1.5], [y - 0.4, y + 0.4], color="black", linewidth=1.4)
        if ours[i] is not None:
            ax.plot([ours[i] - 1.5, ours[i] - 1.5], [y - 0.4, y + 0.4], color="red", linewidth=1.4, linestyle="--")
    ax.set_yticks(range(episodes), [keys[episodes - 1 - i] for i in range(episodes)])
    ax.set_xlabel("step (green: oracle signal is 1; lower strip: digail's code per step; black: MimicGen's "
                  "boundary, red dashed: exported)", fontsize=8)
    ax.set_title(title, fontsize=9)
    fig.tight_layout()
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=110)
    plt.close(fig)
    print(f"wrote {path}")


def main() -> None:
    parser = argparse.ArgumentParser(description=(__doc__ or "").splitlines()[0])
    sub = parser.add_subparsers(dest="command", required=True)
    s = sub.add_parser("score", help="score an export's boundaries against MimicGen's oracle signal")
    s.add_argument("exported", type=Path)
    s.add_argument("oracle", type=Path)
    s.add_argument("--oracle-signal", required=True)
    s.add_argument("--run", type=Path, help="the run folder whose codes.npz the figure shows")
    s.add_argument("--figure", type=Path)
    s.add_argument("--json", type=Path)
    s.add_argument("--command", action="append", default=[], help="a command that made the export (recorded)")
    s.add_argument("--offsets", type=int, nargs=2, default=[10, 20], metavar=("LO", "HI"),
                   help="MimicGen term offsets of every signalled sub-task for its sanity check (Stack's: 10 20)")
    args = parser.parse_args()
    own = [a for i, a in enumerate(sys.argv) if a != "--command" and (i == 0 or sys.argv[i - 1] != "--command")]
    score(args.exported, args.oracle, args.oracle_signal, args.run, args.figure, args.json,
          [*args.command, " ".join(["python", *own])], offsets=tuple(args.offsets))


if __name__ == "__main__":
    main()
