"""ROT's recipe on few-demonstration Fetch, a one-seed screen: SAC on the cheap schedule, a transport reward, BC
kept by the Q-filter. Reads the run folders `benchmarks/fetch_fewdemo.sh` wrote and prints the results page's table.

    benchmarks/fetch_fewdemo.sh 4 digail-l2-rel-argmax-ot-qf-sacfast 0 150
    benchmarks/fetch_fewdemo.sh 4 digail-l2-rel-argmax-ots-qf-sacfast 0 150   # then continued: ... 0 300
    benchmarks/fetch_fewdemo.sh 4 flatbc-l2-rel-ot-qf-sacfast 0 150
    benchmarks/fetch_fewdemo.sh 1 digail-l2-rel-argmax-ot-qf-sacfast 0 150
    benchmarks/fetch_fewdemo.sh 4 digail-l2-argmax-otd-qf-sacfast 0 150      # then continued: 300, 500
    benchmarks/fetch_fewdemo.sh 4 digail-l2-argmax-otl-qf-sacfast 0 300
    python benchmarks/studies/fetch_rot_screen.py runs/fetchfew --out benchmarks/studies/results/fetch_rot_screen.json

Per run: the 100-episode evaluations (after 150k env steps, `eval.iteration-150.json` where the run was continued,
and at its end), the best 20-episode periodic success, and over training the transport reward per agent step and
the share of expert steps whose BC term the Q-filter kept (the medians over iterations 1-10 and the last 10).
"""

from __future__ import annotations

import argparse
import csv
import importlib.util
import json
import statistics
import sys
from pathlib import Path
from types import ModuleType
from typing import Any


def _benchmark(name: str) -> ModuleType:
    """benchmarks/<name>.py, loaded from its file once (this study lives one folder below it)."""
    if name in sys.modules:
        return sys.modules[name]
    spec = importlib.util.spec_from_file_location(name, Path(__file__).resolve().parents[1] / f"{name}.py")
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    sys.modules[name] = module
    spec.loader.exec_module(module)
    return module


md_head = _benchmark("fetch_fewdemo").md_head

METHODS = (
    (4, "digail-l2-rel-argmax-ot-qf-sacfast", "optimal transport on D's view, BC Q-filtered, SAC"),
    (4, "digail-l2-rel-argmax-ots-qf-sacfast", "sub-task-aware optimal transport, BC Q-filtered, SAC"),
    (4, "flatbc-l2-rel-ot-qf-sacfast", "the first row from the flat behaviour-cloned start (one code)"),
    (1, "digail-l2-rel-argmax-ot-qf-sacfast", "the first row with 1 demonstration"),
    (4, "digail-l2-argmax-otd-qf-sacfast",
     "optimal transport, Euclidean cost on the distances view, BC Q-filtered, SAC"),
    (4, "digail-l2-argmax-otl-qf-sacfast", "the same on the log-distances view"),
)
"""(demonstrations, method of `fetch_fewdemo.sh`, what the row is), in the table's order"""
EVAL_KEYS = ("success_rate", "grasp_rate", "lift_rate")


def _median(records: list[dict[str, str]], key: str) -> float | None:
    values = [float(r[key]) for r in records if r.get(key) not in (None, "", "nan")]
    return round(statistics.median(values), 3) if values else None


def collect(root: Path, seed: int) -> list[dict[str, Any]]:
    rows = []
    for demos, method, what in METHODS:
        run = root / f"d{demos}" / f"{method}_s{seed}"
        if not (run / "eval.json").is_file():
            continue
        with (run / "metrics.csv").open() as f:
            records = list(csv.DictReader(f))
        iterations = json.loads((run / "config.json").read_text())["train"]["iterations"]
        evals = {iterations: json.loads((run / "eval.json").read_text())}
        for earlier in run.glob("eval.iteration-*.json"):
            evals[int(earlier.stem.split("-")[-1])] = json.loads(earlier.read_text())
        periodic = [float(r["eval/success_rate"]) for r in records if r.get("eval/success_rate")]
        rows.append({
            "method": method, "what": what, "demos": demos, "seed": seed, "env_steps": iterations * 1000,
            "evaluations": {str(k * 1000): {key: evals[k].get(key) for key in EVAL_KEYS} for k in sorted(evals)},
            "periodic_success_max": max(periodic) if periodic else None,
            "ot_reward_per_step_first10": _median(records[1:11], "reward/ot_episode"),
            "ot_reward_per_step_last10": _median(records[-10:], "reward/ot_episode"),
            "bc_kept_first10": _median(records[1:11], "losses/bc_kept"),
            "bc_kept_last10": _median(records[-10:], "losses/bc_kept"),
            "command": " then ".join(f"benchmarks/fetch_fewdemo.sh {demos} {method} {seed} {k}" for k in sorted(evals)),
        })
    return rows


def markdown(rows: list[dict[str, Any]]) -> str:
    lines = md_head(["reward and learner", "demonstrations", "env steps", "success", "grasp", "lift",
                     "periodic success, best", "transport reward per step, first / last 10 iterations",
                     "BC kept by the Q-filter, first / last 10"])
    for row in rows:
        last = list(row["evaluations"])[-1]
        for steps, ev in row["evaluations"].items():
            # the training curves' columns once, on the run's last evaluation
            over = (f"{row['periodic_success_max']:.2f} | {row['ot_reward_per_step_first10']:.3f} / "
                    f"{row['ot_reward_per_step_last10']:.3f} | {row['bc_kept_first10']:.2f} / "
                    f"{row['bc_kept_last10']:.2f}") if steps == last else "(the run continued below) | | "
            lines.append(f"| {row['what']} | {row['demos']} | {int(steps) // 1000}k | {ev['success_rate']:.2f} | "
                         f"{ev['grasp_rate']:.2f} | {ev['lift_rate']:.2f} | {over} |")
    return "\n".join(lines)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("root", type=Path, help="the folder holding d<N>/<method>_s<seed> run folders")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--out", type=Path)
    args = parser.parse_args()
    rows = collect(args.root, args.seed)
    if args.out:
        args.out.write_text(json.dumps({"rows": rows}, indent=1) + "\n")
    print(markdown(rows))


if __name__ == "__main__":
    main()
