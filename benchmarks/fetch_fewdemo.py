"""Few-demonstration multi-stage tasks (FetchPickAndPlace, the landmark route): the table, the learning curves and
the results file from the run folders that `benchmarks/fetch_fewdemo.sh` / `benchmarks/route_fewdemo.sh` write.

    python benchmarks/fetch_fewdemo.py runs/fetchfew [--task fetch]
        [--out benchmarks/results/fetch-few-demos/fetch_fewdemo.json]
        [--markdown FILE] [--figure benchmarks/results/figures/fetch_fewdemo_curves.png]
    python benchmarks/fetch_fewdemo.py runs/routefew --task route \
        --out benchmarks/results/landmark-route/route_fewdemo.json ...

Per run folder (`runs/fetchfew/d<N>/<method>_s<seed>`, the VAEs as `bc_k4_s<seed>` and `bc_k1_s<seed>`): the
demonstrations N, the method, the seed, the env steps trained, the 100-episode evaluation (`eval.json`: Fetch's
success, grasp and lift rates, the dense return that the paper's Table 2 reports and the sparse return; the route's
success, legs done and landmarks visited out of turn; a run without it is
listed as `running` with its last periodic evaluation), the learning curve (success of the 20-episode evaluation
every 5 PPO iterations or 20k SAC steps against env steps), the env steps where that curve first reached 0.5 and
0.9 success, and the command that made the run. Medians over seeds per (N, method) go under `table`.
"""

from __future__ import annotations

import argparse
import csv
import json
import shlex
from pathlib import Path
from typing import Any

import numpy as np

METHODS = {
    "bc_k4": "BC (the VAE's policy, K = 4)",
    "bc_k1": "BC, flat (one code)",
    "bc_k2": "BC (the VAE's policy, K = 2)",
    "bc_k8": "BC (the VAE's policy, K = 8)",
    "gail-l2": "GAIL + L2, fresh policy",
    "flatbc-l2": "GAIL + L2 from the flat BC policy",
    "digail-l2": "Directed-Info GAIL + L2",
    "gail-l2-sac": "GAIL + L2 + SAC, fresh policy",
    "flatbc-l2-sac": "GAIL + L2 + SAC from the flat BC policy",
    "digail-l2-sac": "Directed-Info GAIL + L2 + SAC",
    "gail": "GAIL, fresh policy",
    "flatbc-gail": "GAIL from the flat BC policy",
    "digail": "Directed-Info GAIL",
    "flatbc-gail-l2": "GAIL + L2 from the flat BC policy",
    "flatbc-gail-l2-gp": "GAIL + L2 from the flat BC policy, D's gradient penalty 10",
    "digail-l2-gp": "Directed-Info GAIL + L2, D's gradient penalty 10",
    "flatbc-gail-l2-rel": "GAIL + L2 from the flat BC policy, D on the relative view",
    "gail-l2-rel": "GAIL + L2, fresh policy, D on the relative view",
    "flatbc-l2-rel": "GAIL + L2 from the flat BC policy, D on the relative view",
    "digail-l2-rel": "Directed-Info GAIL + L2, D on the relative view",
    "flatbc-l2-rel-gp-logit": "GAIL + L2 from the flat BC policy, relative view, penalty 10, logit reward",
    "digail-l2-rel-gp-logit": "Directed-Info GAIL + L2, relative view, penalty 10, logit reward",
    "digail-l2-rel-argmax": "Directed-Info GAIL + L2, relative view, q's argmax codes in every training env",
    "digail-l2-rel-shuffle": "Directed-Info GAIL + L2, relative view, codes shuffled each step",
    "digail-l2-rel-qtrain": "Directed-Info GAIL + L2, relative view, q trained with the policy",
    "digail-l2-rel-nobonus": "Directed-Info GAIL + L2, relative view, no directed-info bonus",
    "digail-l2-rel-k2": "Directed-Info GAIL + L2, relative view, K = 2",
    "digail-l2-rel-k8": "Directed-Info GAIL + L2, relative view, K = 8",
    "flatbc-l2-rel-1m": "GAIL + L2 from the flat BC policy, D on the relative view, to 1M steps",
    "digail-l2-rel-argmax-1m": "Directed-Info GAIL + L2, relative view, q's argmax codes, to 1M steps",
    "flatbc-l2-rel-sac": "GAIL + L2 + SAC from the flat BC policy, D on the relative view",
    "digail-l2-rel-sac": "Directed-Info GAIL + L2 + SAC, D on the relative view",
}
"""method key (the run folder's name without `_s<seed>`) -> the table's name, in the table's order"""
ABLATIONS = {
    "digail-l2-rel": "Directed-Info GAIL + L2, D on the relative view (K = 4, q frozen, bonus 0.01)",
    "digail-l2-rel-argmax": "codes as evaluation takes them (q's argmax in every env, no replayed codes)",
    "digail-l2-rel-shuffle": "codes shuffled each step",
    "flatbc-l2-rel": "one code (GAIL + L2 from the flat BC policy, relative view)",
    "digail-l2-rel-qtrain": "q unfrozen (trained with the policy, lr 3e-4)",
    "digail-l2-rel-nobonus": "directed-info bonus off",
    "digail-l2-rel-k2": "K = 2",
    "digail-l2-rel-k8": "K = 8",
    "digail-l2-rel-argmax-1m": "codes as evaluation takes them, trained on to 1M env steps",
    "flatbc-l2-rel-1m": "one code, trained on to 1M env steps",
}
"""the rows of the ablation table (what carries Directed-Info GAIL + L2 on Fetch with 4 demonstrations)"""
TASKS = {
    "fetch": {"script": "benchmarks/fetch_fewdemo.sh", "title": "FetchPickAndPlace", "env_id":
              "digail/FetchPickAndPlace-v4", "dataset": "digail/fetchpickandplace/expert-v0",
              "keys": ("success_rate", "grasp_rate", "lift_rate", "dense_return", "sparse_return")},
    "route": {"script": "benchmarks/route_fewdemo.sh", "title": "Landmark route", "env_id": "digail/LandmarkRoute-v0",
              "dataset": "digail/landmarkroute/expert-v0",
              "keys": ("success_rate", "legs_done", "wrong_visits", "mean_return")},
}
"""per task: the job script, the figure's title, env and dataset, and the evaluation keys the table reports"""


def _curve(run: Path) -> list[tuple[float, float]]:
    """(env step, success rate) of the periodic evaluations in the run's metrics.csv."""
    path = run / "metrics.csv"
    if not path.is_file():
        return []
    with path.open() as f:
        return [(float(r["step"]), float(r["eval/success_rate"])) for r in csv.DictReader(f)
                if r.get("eval/success_rate")]


def _train_minutes(run: Path) -> float | None:
    """Training wall time in minutes, from each iteration's env steps over its `perf/sps` (periodic evaluations
    and the final one not included): the CPU cost of a run, one core per job."""
    path = run / "metrics.csv"
    if not path.is_file():
        return None
    with path.open() as f:
        rows = [(float(r["step"]), float(r["perf/sps"])) for r in csv.DictReader(f) if r.get("perf/sps")]
    if not rows:
        return None
    seconds, last = 0.0, 0.0
    for step, sps in rows:
        seconds += (step - last) / sps if sps > 0 else 0.0
        last = step
    return round(seconds / 60, 1)


def _late_mean(run: Path, key: str, rows: int = 10) -> float | None:
    """The mean of a metrics.csv column over the run's last `rows` iterations that logged it."""
    path = run / "metrics.csv"
    if not path.is_file():
        return None
    with path.open() as f:
        values = [float(r[key]) for r in csv.DictReader(f) if r.get(key)]
    return float(np.mean(values[-rows:])) if values else None


def _steps_to(curve: list[tuple[float, float]], level: float) -> float | None:
    return next((step for step, success in curve if success >= level), None)


def _command(run: Path, script: str) -> str:
    """What the task's job script ran for this folder (the job line that reproduces it)."""
    demos = run.parent.name.removeprefix("d")
    name, _, seed = run.name.rpartition("_s")
    method = {"bc_k4": "bc", "bc_k1": "flatbc", "bc_k2": "bc2", "bc_k8": "bc8"}.get(name, name)
    words = [script, demos, method, seed]
    config = run / "config.json"
    lines = variant("route" if "route" in script else "fetch", method)
    if not name.startswith("bc_") and "continue" not in lines and config.is_file():
        # a length other than the script's default (the variant's budget) is its fourth argument
        iterations = json.loads(config.read_text()).get("train", {}).get("iterations")
        default = 2000 if "route" in script else int(lines.get("budget", ["100"])[0])
        if iterations not in (None, default):
            words.append(str(iterations))
    return shlex.join(words)


VARIANTS = Path(__file__).resolve().parent / "variants"
"""the variants the job scripts run: `variants/<task>/<method>.variant`, one per method name"""


def variant(task: str, method: str) -> dict[str, list[str]]:
    """A job script's variant file as directive -> its words (`flags`: the `digail train` flags); empty for a
    method without one."""
    path = VARIANTS / task / f"{method}.variant"
    out: dict[str, list[str]] = {}
    for line in path.read_text().splitlines() if path.is_file() else []:
        words = line.split()
        if not words or words[0].startswith("#"):
            continue
        if words[0].startswith("--"):
            out.setdefault("flags", []).extend(words)
        else:
            out[words[0]] = words[1:]
    return out


def record(run: Path, task: str = "fetch") -> dict[str, Any]:
    """One run folder's record: what it is, its learning curve, its late D scalars and its evaluation."""
    name, _, seed = run.name.rpartition("_s")
    curve = _curve(run)
    rec: dict[str, Any] = {"demos": int(run.parent.name.removeprefix("d")), "method": name, "seed": int(seed),
                           "run": str(run), "command": _command(run, str(TASKS[task]["script"])), "curve": curve,
                           "env_steps": curve[-1][0] if curve else 0.0, "train_minutes": _train_minutes(run),
                           "steps_to_0.5": _steps_to(curve, 0.5), "steps_to_0.9": _steps_to(curve, 0.9),
                           "late_disc_acc_expert": _late_mean(run, "disc/acc_expert"),
                           "late_disc_reward": _late_mean(run, "rollout/disc_reward")}
    ev = run / "eval.json"
    if ev.is_file():
        m = json.loads(ev.read_text())
        rec.update(status="done", episodes=m["episodes"], **{k: m[k] for k in TASKS[task]["keys"]})
    else:
        rec.update(status="running", last_periodic_success=curve[-1][1] if curve else None)
    return rec


def md_head(columns: list[str]) -> list[str]:
    """A markdown table's header line and the line under it."""
    return ["| " + " | ".join(columns) + " |", "| " + " | ".join(["---"] * len(columns)) + " |"]


def collect(root: Path, task: str = "fetch") -> list[dict[str, Any]]:
    records = []
    for run in sorted(root.glob("d*/*_s*")):
        name, _, seed = run.name.rpartition("_s")
        if name in METHODS and run.is_dir() and seed.isdigit():
            records.append(record(run, task))
    return records


def table(records: list[dict[str, Any]], task: str = "fetch") -> list[dict[str, Any]]:
    rows = []
    for demos in sorted({r["demos"] for r in records}):
        for method in METHODS:
            done = [r for r in records if r["demos"] == demos and r["method"] == method and r["status"] == "done"]
            if not done:
                continue
            row: dict[str, Any] = {"demos": demos, "method": method, "seeds": [r["seed"] for r in done],
                                   "env_steps": max(r["env_steps"] for r in done)}
            for k in TASKS[task]["keys"]:
                row[f"per_seed_{k}"] = [r[k] for r in done]
                row[f"median_{k}"] = float(np.median([r[k] for r in done]))
            rows.append(row)
    return rows


def markdown(rows: list[dict[str, Any]], task: str = "fetch") -> str:
    others = TASKS[task]["keys"][1:]
    names = {"grasp_rate": "grasp", "lift_rate": "lift", "dense_return": "dense return",
             "sparse_return": "sparse return", "legs_done": "legs done", "wrong_visits": "out-of-turn visits",
             "mean_return": "return"}
    lines = ["| demonstrations | method | success, per seed (median) | "
             + " | ".join(f"{names[k]} (median)" for k in others) + " | env steps | seeds |",
             "| " + " | ".join(["---"] * (len(others) + 5)) + " |"]
    for r in rows:
        per = " / ".join(f"{v:.2f}" for v in r["per_seed_success_rate"])
        steps = f"{r['env_steps'] / 1000:.0f}k" if r["env_steps"] else "0"
        cells = " | ".join(f"{r[f'median_{k}']:.2f}" for k in others)
        lines.append(f"| {r['demos']} | {METHODS[r['method']]} | {per} (**{r['median_success_rate']:.2f}**) "
                     f"| {cells} | {steps} | {' / '.join(map(str, r['seeds']))} |")
    return "\n".join(lines) + "\n"


def ablation_markdown(records: list[dict[str, Any]], demos: int = 4) -> str:
    """The ablation table: per variant of Directed-Info GAIL + L2 with `demos` demonstrations, success per seed, the
    median grasp rate, the env steps to 0.5 and 0.9 success of the learning curve, and D's expert accuracy and
    reward per step over the last 10 iterations (medians over seeds)."""
    def steps(v: float | None) -> str:
        return "not reached" if v is None else f"{v / 1000:.0f}k"

    def med(values: list[float | None]) -> str:
        vals = [v for v in values if v is not None]
        return f"{np.median(vals):.2f}" if vals else "-"

    lines = ["| variant | success, per seed (median) | grasp (median) | steps to 0.5 | steps to 0.9 | D's expert "
             "accuracy, last 10 iterations | D's reward per step, last 10 iterations | seeds |",
             "| --- | --- | --- | --- | --- | --- | --- | --- |"]
    for method, label in ABLATIONS.items():
        done = [r for r in records if r["demos"] == demos and r["method"] == method and r["status"] == "done"]
        if not done:
            continue
        per = " / ".join(f"{r['success_rate']:.2f}" for r in done)
        median = float(np.median([r["success_rate"] for r in done]))
        to5, to9 = (" / ".join(steps(r[key]) for r in done) if any(r[key] is not None for r in done)
                    else "not reached" for key in ("steps_to_0.5", "steps_to_0.9"))
        grasp = med([r.get("grasp_rate") for r in done])
        lines.append(f"| {label} | {per} (**{median:.2f}**) | {grasp} | {to5} | {to9} | "
                     f"{med([r['late_disc_acc_expert'] for r in done])} | {med([r['late_disc_reward'] for r in done])} "
                     f"| {' / '.join(str(r['seed']) for r in done)} |")
    return "\n".join(lines) + "\n"


def _seeds(n: int) -> str:
    return f"{n} seed{'s' if n > 1 else ''}"


def figure(records: list[dict[str, Any]], path: Path, task: str = "fetch") -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    # panels for the settings with a trained run (BC alone is a level, drawn as a dashed line in each panel)
    settings = sorted({r["demos"] for r in records if r["curve"]}) or sorted({r["demos"] for r in records})
    fig, axes = plt.subplots(1, len(settings), figsize=(6 * len(settings), 5.2), squeeze=False, sharey=True)
    # the headline methods only: the probes and ablations have the ablation table (their curves would crowd it)
    # (a run continued to 1M is drawn instead of its 410k start, which is the first part of its curve)
    probes = ("-gp", "-argmax", "-shuffle", "-qtrain", "-nobonus", "-k2", "-k8")
    headline = [m for m in METHODS if m.endswith("-1m") or not any(p in m for p in probes)]
    colours = {m: f"C{i % 10}" for i, m in enumerate(m for m in headline if any(r["method"] == m for r in records))}
    for ax, demos in zip(axes[0], settings, strict=True):
        have = {r["method"] for r in records if r["demos"] == demos}
        for method in (m for m in headline if m in have and f"{m}-1m" not in have):
            label = METHODS[method]
            mine = [r for r in records if r["demos"] == demos and r["method"] == method]
            curves = [dict(r["curve"]) for r in mine if r["curve"]]
            if curves:  # the mean over seeds at the steps every seed evaluated, and the seeds' range as a band
                steps = sorted(set.intersection(*(set(c) for c in curves)))
                values = np.array([[c[x] for x in steps] for c in curves])
                x = np.array(steps) / 1000
                ax.plot(x, values.mean(0), color=colours[method], label=f"{label} ({_seeds(len(curves))})")
                if len(curves) > 1:
                    ax.fill_between(x, values.min(0), values.max(0), color=colours[method], alpha=0.12)
            levels = [r["success_rate"] for r in mine if not r["curve"] and r["status"] == "done"]
            if levels:  # a policy that was not trained: its mean level as a line
                ax.axhline(float(np.mean(levels)), color=colours[method], ls="--", alpha=0.7,
                           label=f"{label} ({_seeds(len(levels))})")
        ax.set_title(f"{TASKS[task]['title']}, {demos} demonstration{'s' if demos > 1 else ''}")
        ax.set_xlabel("env steps (thousands)")
        ax.grid(alpha=0.3)
        ax.legend(fontsize=7, loc="upper center", bbox_to_anchor=(0.5, -0.2), ncol=1, frameon=False)
    axes[0][0].set_ylabel("success rate, mean of seeds")
    fig.tight_layout()
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=110)
    plt.close(fig)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("root", type=Path, help="the folder the job script wrote (runs/fetchfew, runs/routefew)")
    parser.add_argument("--task", choices=sorted(TASKS), default="fetch")
    parser.add_argument("--out", type=Path, default=Path("benchmarks/results/fetch-few-demos/fetch_fewdemo.json"))
    parser.add_argument("--markdown", type=Path)
    parser.add_argument("--figure", type=Path)
    parser.add_argument("--page", type=Path, help="a Markdown page whose `<!-- TASK_fewdemo:start -->` and "
                        "`<!-- TASK_fewdemo:end -->` markers take the table (the route's: docs/results.md; Fetch's: "
                        "docs/experiments/2026-12-07-results-history.md)")
    args = parser.parse_args()
    task = TASKS[args.task]
    records = collect(args.root, args.task)
    rows = table(records, args.task)
    dataset = f"{task['dataset']} (the first N demonstrations)"
    args.out.write_text(json.dumps({"env_id": task["env_id"], "dataset": dataset,
                                    "methods": METHODS, "table": rows, "runs": records}, indent=1) + "\n")
    text = markdown(rows, args.task)
    if args.markdown:
        args.markdown.write_text(text)
    if args.figure:
        figure(records, args.figure, args.task)
    if args.page:
        from digail.sweep.publish import replace_between_markers

        replace_between_markers(args.page, (f"<!-- {args.task}_fewdemo:start -->", f"<!-- {args.task}_fewdemo:end -->"),
                                text.rstrip("\n"))
        if args.task == "fetch":
            replace_between_markers(args.page, ("<!-- fetch_ablations:start -->", "<!-- fetch_ablations:end -->"),
                                    ablation_markdown(records).rstrip("\n"))
    print(text, end="")


if __name__ == "__main__":
    main()
