"""`make demo` (that is `digail run`, Circle-World by default) of this checkout against another commit's code, side
by side in one run.

    python benchmarks/studies/demo_speed.py --baseline REV [--rounds 2] [--seed 0] [--env digail/CircleWorld-v0]

Each round runs the whole pipeline once with the baseline's `src` (extracted with `git archive`) and once with this
checkout's, in fresh processes and alternating which goes first, so that a shared machine's drifting load hits both
alike; one torch thread each (`OMP_NUM_THREADS=1`), run folders in a temporary directory. Writes
runs/bench/demo_speed.json (`--out`; published: benchmarks/results/speed/demo_speed.json): each side's
wall-clock seconds per round and stage (`timings.json` of the run folder),
the medians, the new-over-old speed-up (median of per-round ratios) and the headline results of every run
(evaluation, segmentation, composition), so that "the same results" can be checked.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

import numpy as np

ROOT = Path(__file__).resolve().parents[2]
RESULT_KEYS = {"eval.json": ("", ("mean_return", "order_correct_rate", "radius_error", "success_rate")),
               "segmentation.json": ("seg_", ("accuracy", "nmi", "boundary_f1")),
               "compose.json": ("composed_", ("order_reversed_rate",))}
"""run-folder file -> (prefix, keys) of the headline results recorded per run"""


def run_side(src: Path, out: Path, args: argparse.Namespace, extra: list[str]) -> dict[str, Any]:
    """One `digail run` (plus `extra` flags) with the code under `src`; its wall time, stage timings and headline
    results."""
    env = {**os.environ, "PYTHONPATH": str(src), "OMP_NUM_THREADS": "1", "MUJOCO_GL": "egl"}
    t0 = time.perf_counter()
    subprocess.run([sys.executable, "-m", "digail.cli", "run", args.env, "--out", str(out), "--seed", str(args.seed),
                    "--force", *extra], env=env, check=True, capture_output=True, text=True)
    sample: dict[str, Any] = {"wall_s": time.perf_counter() - t0}
    timings = out / "timings.json"
    if timings.is_file():
        sample["stages"] = json.loads(timings.read_text())
    for name, (prefix, keys) in RESULT_KEYS.items():
        path = out / name
        if path.is_file():
            data = json.loads(path.read_text())
            sample.update({prefix + k: data[k] for k in keys if isinstance(data.get(k), int | float)})
    return sample


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--baseline", required=True, help="git revision to compare against (e.g. main)")
    parser.add_argument("--env", default="digail/CircleWorld-v0")
    parser.add_argument("--rounds", type=int, default=2)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--new-no-smoothing-pair", action="store_true",
                        help="run this checkout with --no-smoothing-pair: the baseline's work where the baseline "
                             "predates the second VAE (57dc4a4 does)")
    parser.add_argument("--out", default="runs/bench/demo_speed.json")
    args = parser.parse_args()

    samples: dict[str, list[dict[str, Any]]] = {"old": [], "new": []}
    with tempfile.TemporaryDirectory() as tmp:
        archive = subprocess.run(["git", "-C", str(ROOT), "archive", args.baseline, "src"], check=True,
                                 capture_output=True).stdout
        subprocess.run(["tar", "-x", "-C", tmp], input=archive, check=True)
        sides = {"old": Path(tmp) / "src", "new": ROOT / "src"}
        for r in range(args.rounds):
            order = ["old", "new"] if r % 2 == 0 else ["new", "old"]
            for name in order:
                extra = ["--no-smoothing-pair"] if name == "new" and args.new_no_smoothing_pair else []
                samples[name].append(run_side(sides[name], Path(tmp) / f"run_{name}_{r}", args, extra))
            print(f"round {r + 1}: " + ", ".join(f"{k} {samples[k][-1]['wall_s']:.0f}s" for k in order), flush=True)
            write_results(args, samples)  # after every round: a long run cut short keeps its finished rounds


def write_results(args: argparse.Namespace, samples: dict[str, list[dict[str, Any]]]) -> None:
    def col(name: str, key: str) -> np.ndarray:
        return np.array([float(s[key]) for s in samples[name]])

    results: dict[str, Any] = {"baseline": args.baseline, "env": args.env, "seed": args.seed,
                               "rounds": len(samples["new"]), "command": f"digail run {args.env} --seed {args.seed}",
                               "new_no_smoothing_pair": args.new_no_smoothing_pair,
                               "cpus": len(os.sched_getaffinity(0)), "loadavg": list(os.getloadavg())}
    for name in samples:
        results[f"{name}_wall_s"] = float(np.median(col(name, "wall_s")))
    results["speedup"] = float(np.median(col("old", "wall_s") / col("new", "wall_s")))
    results["results"] = {name: [{k: v for k, v in s.items() if k not in ("wall_s", "stages")} for s in runs]
                          for name, runs in samples.items()}
    results["samples"] = samples
    Path(args.out).parent.mkdir(parents=True, exist_ok=True)
    Path(args.out).write_text(json.dumps(results, indent=2) + "\n")
    print(json.dumps({k: v for k, v in results.items() if k != "samples"}, indent=2), flush=True)

if __name__ == "__main__":
    main()
