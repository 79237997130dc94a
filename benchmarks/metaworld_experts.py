"""Meta-World's scripted experts on digail's Meta-World envs: success, steps to success and phase structure.

    python benchmarks/metaworld_experts.py       # every task, 20 episodes -> results/metaworld/metaworld_experts.json
    python benchmarks/metaworld_experts.py --tasks pick-place-v3 --episodes 5 --out runs/mw.json
    python benchmarks/metaworld_experts.py --markdown   # the docs' table of the shipped tasks from the JSON

Each episode (reset with seed `seed + i`, random placements) runs the expert for up to `--limit` steps (500,
Meta-World's own limit, not the digail env's shorter one) and records the first step at which `info["success"]`
held, and the expert's phase labels up to it (`info["subtask"]`): the phases seen, the number of phase runs (a
phase the expert returns to counts again) before and after merging runs shorter than
`digail.envs.metaworld.MIN_SEGMENT` steps. The digail env's time limit of a task (`EPISODE_STEPS`) was set from
this table: 1.5 times the slowest successful episode's steps to success, rounded up to 50, at least 100 and at most
500.
"""

from __future__ import annotations

import argparse
import json
import math
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np

from digail.envs.metaworld import EPISODE_STEPS, MIN_SEGMENT, MetaWorldEnv, merge_short_runs

HERE = Path(__file__).resolve().parent


def runs_of(labels: np.ndarray) -> list[int]:
    """The phases of consecutive runs of equal labels."""
    labels = np.asarray(labels)
    return labels[np.r_[True, np.diff(labels) != 0]].tolist() if len(labels) else []


def suggested_limit(first_successes: list[int]) -> int:
    """The time limit the table suggests: 1.5 x the slowest success, rounded up to 50, within [100, 500]."""
    if not first_successes:
        return 500
    return int(min(500, max(100, 50 * math.ceil(1.5 * max(first_successes) / 50))))


def measure_task(task: str, episodes: int, seed: int, limit: int) -> dict[str, Any]:
    env = MetaWorldEnv(task)
    firsts: list[int] = []
    runs, merged_runs, phases_seen = [], [], set()
    start, steps = time.perf_counter(), 0
    try:
        for i in range(episodes):
            obs, info = env.reset(seed=seed + i)
            labels, first = [info["subtask"]], None
            for t in range(limit):
                obs, _, _, _, info = env.step(env.expert.action(obs))
                steps += 1
                if info["success"]:
                    first = t + 1
                    break
                labels.append(info["subtask"])
            lab = np.asarray(labels)
            phases_seen |= set(lab.tolist())
            runs.append(len(runs_of(lab)))
            merged_runs.append(len(runs_of(merge_short_runs(lab))))
            if first is not None:
                firsts.append(first)
    finally:
        env.close()
    return {"task": task, "episodes": episodes, "phases": env.expert.phases,
            "phases_seen": sorted(int(p) for p in phases_seen),
            "success_rate": len(firsts) / episodes,
            "steps_to_success_mean": float(np.mean(firsts)) if firsts else None,
            "steps_to_success_max": int(max(firsts)) if firsts else None,
            "runs_mean": float(np.mean(runs)), "runs_max": int(max(runs)),
            "merged_runs_mean": float(np.mean(merged_runs)), "merged_runs_max": int(max(merged_runs)),
            "suggested_limit": suggested_limit(firsts), "episode_steps": EPISODE_STEPS[task],
            "steps_per_second": steps / (time.perf_counter() - start)}


SHIPPED = ("pick-place-v3", "assembly-v3", "stick-pull-v3", "shelf-place-v3", "basketball-v3", "disassemble-v3",
           "peg-insert-side-v3", "box-close-v3", "hammer-v3")
"""the tasks whose demonstrations digail ships (scripts/metaworld_datasets.sh)"""


def markdown(result: dict[str, Any], tasks: tuple[str, ...] = SHIPPED) -> str:
    """The table of the how-to: success, steps to success, phases and phase runs of `tasks`."""
    from digail.data.minari_io import SHIPPED_ROOT

    rows = {r["task"]: r for r in result["tasks"]}
    # the shipped demonstrations end at the first success: their terminated episodes are the successes
    shipped = {d["env"]: d for d in json.loads((SHIPPED_ROOT / "MANIFEST.json").read_text())["datasets"]}
    lines = [f"| task | success ({result['tasks'][0]['episodes']} episodes) | steps to success: mean (max) | phases "
             f"(seen) | phase runs per episode: raw / merged (max) | time limit | shipped: successes, mean length |",
             "| --- | --- | --- | --- | --- | --- | --- |"]
    for task in tasks:
        r, ship = rows[task], shipped[f"metaworld/{task}"]
        steps = (f"{r['steps_to_success_mean']:.0f} ({r['steps_to_success_max']})"
                 if r["steps_to_success_mean"] is not None else "-")
        lines.append(f"| {task} | {r['success_rate']:.2f} | {steps} | {r['phases']} ({len(r['phases_seen'])}) | "
                     f"{r['runs_mean']:.1f} / {r['merged_runs_mean']:.1f} ({r['merged_runs_max']}) | "
                     f"{r['episode_steps']} | {ship['terminated']} / {ship['episodes']}, {ship['length_mean']:.0f} |")
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--tasks", nargs="+", default=sorted(EPISODE_STEPS), choices=sorted(EPISODE_STEPS))
    parser.add_argument("--episodes", type=int, default=20)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--limit", type=int, default=500)
    parser.add_argument("--out", type=Path, default=HERE / "results" / "metaworld" / "metaworld_experts.json")
    parser.add_argument("--markdown", action="store_true", help="print the docs' table from --out and stop")
    args = parser.parse_args(argv)
    if args.markdown:
        print(markdown(json.loads(args.out.read_text())))
        return
    rows = []
    for task in args.tasks:
        rows.append(measure_task(task, args.episodes, args.seed, args.limit))
        r = rows[-1]
        print(f"{task:30s} success {r['success_rate']:.2f} steps {r['steps_to_success_mean']} "
              f"(max {r['steps_to_success_max']}) phases {r['phases']} runs {r['runs_mean']:.1f} "
              f"merged {r['merged_runs_mean']:.1f} limit {r['suggested_limit']}", flush=True)
    args.out.parent.mkdir(parents=True, exist_ok=True)
    command = "python benchmarks/metaworld_experts.py " + " ".join(argv if argv is not None else sys.argv[1:])
    args.out.write_text(json.dumps({"command": command.strip(), "min_segment": MIN_SEGMENT, "seed": args.seed,
                                    "limit": args.limit, "tasks": rows}, indent=1) + "\n")


if __name__ == "__main__":
    main()
