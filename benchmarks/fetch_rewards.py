"""The imitation-reward screen on few-demonstration Fetch: one table and its results file from the run folders
that `benchmarks/fetch_fewdemo.sh N METHOD SEED ITERATIONS` writes (the reward variants are suffixes there).

    python benchmarks/fetch_rewards.py runs/fetchfew --demos 4 --seed 0 \
        --out benchmarks/results/fetch_rewards.json --page docs/results.md

Per run (`runs/fetchfew/d<N>/digail-l2-rel-argmax*_s<seed>`): the 100-episode evaluation at the end (success,
grasp, lift), the periodic success (20 episodes every 5 iterations) at each evaluation, and over training whether
the reward still teaches: D's expert accuracy and the imitation reward per agent step (`rollout/disc_reward`)
over the first and the last 5 iterations, and the spread of that reward over the agent's steps is what the OT rows
show as `reward/ot_episode`. The table goes between `<!-- fetch_rewards:start -->` and `<!-- fetch_rewards:end -->`
in the page.
"""

from __future__ import annotations

import argparse
import csv
import json
from pathlib import Path
from typing import Any

import numpy as np
from fetch_fewdemo import _command, _curve, _train_minutes

BASE = "digail-l2-rel-argmax"
LABELS = {
    "": "today's best: D by binary cross-entropy (GAIL's)",
    "-pu": "D positive-unlabeled (prior 0.5)",
    "-noise": "D's inputs noised (sigma 0.15)",
    "-sn": "D spectrally normalised",
    "-ot": "optimal transport on D's view (no D)",
    "-ots": "sub-task-aware optimal transport (no D)",
    "-otst": "sub-task-aware optimal transport, in order (no D)",
    "-anneal": "D by cross-entropy, BC weight annealed to 0",
    "-ots-anneal": "sub-task-aware optimal transport, BC weight annealed to 0",
    "-ot-anneal": "optimal transport, BC weight annealed to 0",
}
"""suffix after `digail-l2-rel-argmax` -> what the row changes"""


def _column(rows: list[dict[str, str]], key: str, part: slice) -> float | None:
    values = [float(r[key]) for r in rows if r.get(key)][part]
    return float(np.mean(values)) if values else None


def collect(root: Path, demos: int, seed: int) -> list[dict[str, Any]]:
    out = []
    for suffix, label in LABELS.items():
        run = root / f"d{demos}" / f"{BASE}{suffix}_s{seed}"
        metrics = run / "metrics.csv"
        if not metrics.is_file():
            continue
        with metrics.open() as f:
            rows = list(csv.DictReader(f))
        curve = _curve(run)
        rec: dict[str, Any] = {
            "method": BASE + suffix, "label": label, "demos": demos, "seed": seed, "run": str(run),
            "command": _command(run, "benchmarks/fetch_fewdemo.sh"), "curve": curve,
            "env_steps": max((float(r["step"]) for r in rows), default=0.0),
            "train_minutes": _train_minutes(run),
            "disc_acc_expert_first5": _column(rows, "disc/acc_expert", slice(0, 5)),
            "disc_acc_expert_last5": _column(rows, "disc/acc_expert", slice(-5, None)),
            "reward_per_step_first5": _column(rows, "rollout/disc_reward", slice(0, 5)),
            "reward_per_step_last5": _column(rows, "rollout/disc_reward", slice(-5, None)),
            "periodic_success_max": max((s for _, s in curve), default=None),
        }
        ev = run / "eval.json"
        if ev.is_file():
            m = json.loads(ev.read_text())
            rec.update(status="done", episodes=m["episodes"], success_rate=m["success_rate"],
                       grasp_rate=m["grasp_rate"], lift_rate=m["lift_rate"], dense_return=m["dense_return"])
        else:
            rec.update(status="running")
        out.append(rec)
    return out


def _f(x: float | None, digits: int = 2) -> str:
    return "-" if x is None else f"{x:.{digits}f}"


def markdown(records: list[dict[str, Any]]) -> str:
    head = ("| reward | success (100 episodes) | grasp | lift | periodic success, best of the run | "
            "D's expert accuracy, first / last 5 iterations | reward per agent step, first / last 5 iterations | "
            "env steps |\n"
            "| --- | --- | --- | --- | --- | --- | --- | --- |\n")
    lines = []
    for r in records:
        done = r["status"] == "done"
        acc = ("no D" if r["disc_acc_expert_last5"] is None
               else f"{_f(r['disc_acc_expert_first5'])} / {_f(r['disc_acc_expert_last5'])}")
        lines.append(f"| {r['label']} | {_f(r.get('success_rate')) if done else 'running'} | "
                     f"{_f(r.get('grasp_rate'))} | {_f(r.get('lift_rate'))} | {_f(r['periodic_success_max'])} | "
                     f"{acc} | {_f(r['reward_per_step_first5'], 3)} / {_f(r['reward_per_step_last5'], 3)} | "
                     f"{r['env_steps'] / 1000:.0f}k |")
    return head + "\n".join(lines) + "\n"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("root", type=Path)
    parser.add_argument("--demos", type=int, default=4)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--out", type=Path, default=Path("benchmarks/results/fetch_rewards.json"))
    parser.add_argument("--page", type=Path, help="a page with the table's markers, rewritten in place")
    args = parser.parse_args()
    records = collect(args.root, args.demos, args.seed)
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(json.dumps({"env_id": "digail/FetchPickAndPlace-v4", "dataset":
                                    "digail/fetchpickandplace/expert-v0", "runs": records}, indent=1) + "\n")
    table = markdown(records)
    print(table)
    if args.page is not None:
        text = args.page.read_text()
        start, end = "<!-- fetch_rewards:start -->\n", "<!-- fetch_rewards:end -->"
        a, b = text.index(start) + len(start), text.index(end)
        args.page.write_text(text[:a] + table + text[b:])


if __name__ == "__main__":
    main()
