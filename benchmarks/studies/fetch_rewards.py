"""The imitation-reward screen on few-demonstration Fetch: one table and its results file from the run folders
that `benchmarks/fetch_fewdemo.sh N METHOD SEED ITERATIONS` writes (each METHOD's flags: benchmarks/variants/fetch/).

    python benchmarks/studies/fetch_rewards.py runs/fetchfew --demos 4 --seed 0 \
        --out benchmarks/studies/results/fetch_rewards.json \
        --page docs/experiments/2026-12-07-results-history.md

Per run (`runs/fetchfew/d<N>/<method>_s<seed>` for each method of `LABELS`): the 100-episode evaluations after 30
iterations (122,880 env steps: the run's eval.json, or the eval.iteration-30.json a longer run keeps) and after 50
(204,800), the best periodic success (20 episodes every 5 iterations), and whether the reward still teaches: D's
expert accuracy and the imitation reward per agent step (`rollout/disc_reward`) over iterations 1-5 and 26-30. The
table goes between `<!-- fetch_rewards:start -->` and `<!-- fetch_rewards:end -->` in the page. A row whose run
folder is not on this machine keeps its record from the results file (`--out`), so rows measured elsewhere stay.
"""

from __future__ import annotations

import argparse
import csv
import importlib.util
import json
import sys
from pathlib import Path
from types import ModuleType
from typing import Any

import numpy as np


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


fetch_fewdemo = _benchmark("fetch_fewdemo")
_command, _curve, _train_minutes = fetch_fewdemo._command, fetch_fewdemo._curve, fetch_fewdemo._train_minutes

BASE = "digail-l2-rel-argmax"
LABELS = {
    BASE: "today's best: D by binary cross-entropy (GAIL's)",
    BASE + "-pu": "D positive-unlabeled (prior 0.5)",
    BASE + "-noise": "D's inputs noised (sigma 0.15)",
    BASE + "-sn": "D spectrally normalised",
    BASE + "-sonly": "D judges states alone (no actions)",
    "digail-l2-dist-argmax": "D on the distances view (no directions)",
    BASE + "-ot": "optimal transport on D's view (no D)",
    BASE + "-ots": "sub-task-aware optimal transport (no D)",
    BASE + "-otst": "sub-task-aware optimal transport, in order (no D)",
    "digail-l2-argmax-otd": "optimal transport, Euclidean cost on the distances view (no D)",
    "relative:digail-l2-argmax": "today's best on Fetch observed in the relative view (the policy too)",
    BASE + "-anneal": "D by cross-entropy, BC weight annealed to 0",
    BASE + "-ots-anneal": "sub-task-aware optimal transport, BC weight annealed to 0",
    BASE + "-ot-anneal": "optimal transport, BC weight annealed to 0",
}
"""method (`fetch_fewdemo.sh`'s name; `relative:` for a run on the relative-observation env, FETCH_OBS=relative,
whose folders sit beside ROOT in ROOT-rel) -> what the row changes against today's best"""


def _column(rows: list[dict[str, str]], key: str, first: int, last: int) -> float | None:
    """The mean of a metrics.csv column over iterations first..last (None: not logged there)."""
    values = [float(r[key]) for r in rows if r.get(key) and first <= float(r["iteration"]) <= last]
    return float(np.mean(values)) if values else None


def _evaluation(run: Path, iterations: int) -> dict[str, Any] | None:
    """The run's 100-episode evaluation after `iterations` iterations, if it made one."""
    config = json.loads((run / "config.json").read_text()) if (run / "config.json").is_file() else {}
    for path in (run / f"eval.iteration-{iterations}.json", run / "eval.json"):
        if path.name == "eval.json" and config.get("train", {}).get("iterations") != iterations:
            continue
        if path.is_file():
            m = json.loads(path.read_text())
            return {k: m[k] for k in ("episodes", "success_rate", "grasp_rate", "lift_rate", "dense_return")}
    return None


def _longer_run(run: Path) -> bool:
    """Whether the folder holds a run made longer than the screen's 50 iterations that kept no evaluation at 50 (a
    full-budget run of the same method): not the screen's run."""
    config = json.loads((run / "config.json").read_text()) if (run / "config.json").is_file() else {}
    return config.get("train", {}).get("iterations", 0) > 50 and _evaluation(run, 50) is None


def collect(root: Path, demos: int, seed: int, kept: list[dict[str, Any]] | None = None) -> list[dict[str, Any]]:
    """The rows, in `LABELS`' order: from the run folders under `root`, else from `kept` (earlier records)."""
    out = []
    earlier = {(r["method"], r["demos"], r["seed"]): r for r in kept or []}
    for method, label in LABELS.items():
        obs, _, name = method.rpartition(":")
        run = (root.with_name(root.name + "-rel") if obs == "relative" else root) / f"d{demos}" / f"{name}_s{seed}"
        metrics = run / "metrics.csv"
        if not metrics.is_file() or _longer_run(run):
            if (method, demos, seed) in earlier:
                out.append({**earlier[(method, demos, seed)], "label": label})
            continue
        with metrics.open() as f:
            rows = list(csv.DictReader(f))
        curve = _curve(run)
        rec: dict[str, Any] = {
            "method": method, "label": label, "demos": demos, "seed": seed, "run": str(run),
            "command": ("FETCH_OBS=relative " if obs == "relative" else "")
            + _command(run, "benchmarks/fetch_fewdemo.sh"), "curve": curve,
            "env_steps": max((float(r["step"]) for r in rows), default=0.0),
            "train_minutes": _train_minutes(run),
            "disc_acc_expert_it1_5": _column(rows, "disc/acc_expert", 1, 5),
            "disc_acc_expert_it26_30": _column(rows, "disc/acc_expert", 26, 30),
            "reward_per_step_it1_5": _column(rows, "rollout/disc_reward", 1, 5),
            "reward_per_step_it26_30": _column(rows, "rollout/disc_reward", 26, 30),
            "reward_per_step_it46_50": _column(rows, "rollout/disc_reward", 46, 50),
            "periodic_success_max": max((s for _, s in curve), default=None),
            "eval_30": _evaluation(run, 30), "eval_50": _evaluation(run, 50),
        }
        rec["status"] = "done" if (run / "eval.json").is_file() else "running"
        out.append(rec)
    return out


def _f(x: float | None, digits: int = 2) -> str:
    return "-" if x is None else f"{x:.{digits}f}"


def markdown(records: list[dict[str, Any]]) -> str:
    head = ("| reward | success at 123k / 205k env steps (100 episodes) | grasp at 123k / 205k | periodic success, "
            "best | D's expert accuracy, iterations 1-5 / 26-30 | reward per agent step, iterations 1-5 / 26-30 "
            "| env steps |\n| --- | --- | --- | --- | --- | --- | --- |\n")
    lines = []
    for r in records:
        e30, e50 = r["eval_30"] or {}, r["eval_50"] or {}
        acc = ("no D" if "-ot" in r["method"]
               else f"{_f(r['disc_acc_expert_it1_5'])} / {_f(r['disc_acc_expert_it26_30'])}")
        later = "running" if r["status"] == "running" and not e50 else _f(e50.get("success_rate"))
        lines.append(f"| {r['label']} | {_f(e30.get('success_rate'))} / {later} | "
                     f"{_f(e30.get('grasp_rate'))} / {_f(e50.get('grasp_rate'))} | {_f(r['periodic_success_max'])} | "
                     f"{acc} | {_f(r['reward_per_step_it1_5'], 3)} / {_f(r['reward_per_step_it26_30'], 3)} | "
                     f"{r['env_steps'] / 1000:.0f}k |")
    return head + "\n".join(lines) + "\n"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("root", type=Path)
    parser.add_argument("--demos", type=int, default=4)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--out", type=Path, default=Path("benchmarks/studies/results/fetch_rewards.json"))
    parser.add_argument("--page", type=Path, help="a page with the table's markers, rewritten in place")
    args = parser.parse_args()
    kept = json.loads(args.out.read_text())["runs"] if args.out.is_file() else []
    records = collect(args.root, args.demos, args.seed, kept)
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
