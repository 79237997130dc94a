"""The few-demonstration benchmark's table from its run folders (benchmarks/sweeps/fewdemo.toml).

    python benchmarks/fewdemo.py --sweep runs/sweeps/fewdemo [--out benchmarks/results/few-demos/fewdemo.json]
    python benchmarks/fewdemo.py RUN [RUN ...] [--merge [--drop OLD ...]]   # any training or VAE run folders

Per run: env, method, learner, demonstration setting, seed; the environment steps done (`partial` when fewer than
the run's budget); the normalised return of its final 100-episode evaluation (eval.json, written by `digail
evaluate`; for a run stopped early, of its last checkpoint) or, for a run still going, of its last periodic
evaluation (5 episodes, marked `from_curve`); the env steps at which the periodic evaluation first reached 0.9 and
0.95 of the expert (None: not yet); the mean of the periodic evaluations inside a common window of env steps
(`--window`, default 100k-190k: runs stopped at different steps compared at the same steps; None for a run that
stopped before the window's end); the training's wall time (the sum over iterations of steps / steps per second);
and the learning curve (env step, normalised return). Medians over seeds per (env, setting, method, learner, where
Directed-Info GAIL's policy started, the BC term's weight) go under `table`. Published references (1 expert
trajectory of Hopper, as a recent table reports them) go under `references`. `--merge` keeps the entries of
`--out` made from run folders that are not on this machine.
"""

from __future__ import annotations

import argparse
import csv
import json
import math
from pathlib import Path
from typing import Any

import numpy as np

REFERENCES = {
    "note": "1 expert trajectory on Hopper, 1M steps or fewer, as quoted by a recent table (returns; expert 3633)",
    "Hopper-v5": {"expert": 3633, "GAIL": 3536, "IQ-Learn": 3425, "DAC": 3322},
}


def _curve(run: Path) -> list[tuple[float, float]]:
    path = run / "metrics.csv"
    if not path.is_file():
        return []
    out = []
    with path.open() as f:
        for row in csv.DictReader(f):
            v = row.get("eval/normalized_return") or ""
            if v:
                out.append((float(row["step"]), float(v)))
    return out


def _wall_time(run: Path) -> float | None:
    path = run / "metrics.csv"
    if not path.is_file():
        return None
    total, last = 0.0, 0.0
    with path.open() as f:
        for row in csv.DictReader(f):
            sps, step = row.get("perf/sps") or "", float(row["step"])
            if sps and float(sps) > 0 and step > last:
                total += (step - last) / float(sps)
                last = step
    return total


def first_reach(curve: list[tuple[float, float]], level: float) -> float | None:
    """The first env step whose evaluation reached `level` (None: never)."""
    return next((s for s, v in curve if v >= level), None)


WINDOW = (100_000.0, 190_000.0)


def window_mean(curve: list[tuple[float, float]], window: tuple[float, float]) -> float | None:
    """The mean periodic evaluation from window[0] to window[1] env steps (None: the curve stops short of window[1])."""
    lo, hi = window
    inside = [v for s, v in curve if lo <= s <= hi]
    if not inside or max(s for s, _ in curve) < hi:
        return None
    return float(np.mean(inside))


def summarise_run(run: Path, window: tuple[float, float] = WINDOW) -> dict[str, Any] | None:
    config_path = run / "config.json"
    if not config_path.is_file():
        return None
    config = json.loads(config_path.read_text())
    args = config.get("args") or {}
    train = config.get("train") or {}
    kind = config.get("kind")
    method = "bc (vae)" if kind == "vae" else str(config.get("method"))
    learner = None if kind == "vae" else train.get("learner", "ppo")
    if learner == "sac":
        budget = int(train["iterations"]) * int(train["sac"]["steps_per_iteration"])
    elif learner == "ppo":
        budget = int(train["iterations"]) * int(train["ppo"]["batch_size"])
    else:
        budget = 0
    curve = _curve(run)
    steps = max((s for s, _ in curve), default=0.0)
    rec: dict[str, Any] = {
        "run": str(run), "env": config.get("env_id"), "method": method, "learner": learner, "seed": config.get("seed"),
        "demos_episodes": args.get("demos_episodes"), "demos_subsample": args.get("demos_subsample", 1),
        "budget_steps": budget, "curve": [[s, round(v, 4)] for s, v in curve],
    }
    if method == "digail" and learner is not None:
        # Directed-Info GAIL's policy starts from the VAE's decoder or from fresh weights (q's codes either way)
        rec["policy_init"] = "vae" if train.get("init_from_vae", True) else "fresh"
    if float(train.get("bc_weight") or 0.0) > 0:
        rec["bc_weight"] = float(train["bc_weight"])  # the BC / L2 term: its own row
    metrics = run / "metrics.csv"
    if metrics.is_file():
        with metrics.open() as f:
            rows = list(csv.DictReader(f))
        steps = max(steps, float(rows[-1]["step"]) if rows else 0.0)
    rec["env_steps"] = steps
    rec["partial"] = kind != "vae" and steps < budget
    eval_path = run / "eval.json"
    if eval_path.is_file():
        # a stopped run's final evaluation is of its last checkpoint, at `env_steps`
        ev = json.loads(eval_path.read_text())
        rec.update(normalized_return=ev.get("normalized_return"), mean_return=ev.get("mean_return"),
                   eval_episodes=ev.get("episodes"), from_curve=False)
    elif curve:
        rec.update(normalized_return=curve[-1][1], eval_episodes=(config.get("train") or {}).get("eval_episodes"),
                   from_curve=True)
    rec["steps_to_0.9"] = first_reach(curve, 0.9)
    rec["steps_to_0.95"] = first_reach(curve, 0.95)
    rec["window"] = list(window)
    rec["window_mean"] = window_mean(curve, window)
    rec["wall_time_s"] = _wall_time(run)
    return rec


def _grouped(records: list[dict[str, Any]], key: Any) -> list[tuple[tuple[Any, ...], list[dict[str, Any]]]]:
    """The records grouped by `key(record)`, groups in the order of their keys' reprs."""
    groups: dict[tuple[Any, ...], list[dict[str, Any]]] = {}
    for r in records:
        groups.setdefault(key(r), []).append(r)
    return sorted(groups.items(), key=lambda kv: repr(kv[0]))


def table(records: list[dict[str, Any]]) -> list[dict[str, Any]]:
    out = []
    for (env, episodes, every, method, learner, init, bc), rs in _grouped(records, lambda r: (
            r["env"], r["demos_episodes"], r["demos_subsample"], r["method"], r["learner"], r.get("policy_init"),
            r.get("bc_weight"))):
        vals = [r["normalized_return"] for r in rs if isinstance(r.get("normalized_return"), float)
                and math.isfinite(r["normalized_return"])]
        inside = [r["window_mean"] for r in rs if r.get("window_mean") is not None]
        out.append({"env": env, "demos_episodes": episodes, "demos_subsample": every, "method": method,
                    "learner": learner, **({"policy_init": init} if init else {}), **({"bc_weight": bc} if bc else {}),
                    "seeds": sorted(r["seed"] for r in rs),
                    "median_normalized_return": float(np.median(vals)) if vals else None,
                    "median_window_mean": float(np.median(inside)) if inside else None,
                    "window_seeds": sorted(r["seed"] for r in rs if r.get("window_mean") is not None),
                    "partial": any(r.get("partial") for r in rs)})
    return out


def _label(r: dict[str, Any]) -> str:
    learner = r["learner"].upper() if r["learner"] else ""
    name = {"digail": "Directed-Info GAIL", "gail": "GAIL"}.get(r["method"], r["method"])
    init = {"vae": ", policy from the VAE", "fresh": ""}.get(r.get("policy_init") or "", "")
    bc = f", BC term {r['bc_weight']:g}" if r.get("bc_weight") else ""
    return f"{name} + {learner}{init}{bc}"


def draw_curves(records: list[dict[str, Any]], path: Path) -> None:
    """Learning curves: one panel per (env, demonstration setting), one line per run (colour: method and learner),
    BC's median as a dashed line, 0.9 and 0.95 of the expert dotted."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    panels = sorted({(r["env"], r["demos_episodes"], r["demos_subsample"]) for r in records}, key=repr)
    labels = sorted({_label(r) for r in records if r["learner"] is not None})
    colour = {lab: matplotlib.colormaps["tab10"](i) for i, lab in enumerate(labels)}
    cols = min(2, len(panels))
    rows = -(-len(panels) // cols)
    fig, axes = plt.subplots(rows, cols, figsize=(6.5 * cols, 4.2 * rows), squeeze=False)
    for ax in axes.flat[len(panels):]:
        ax.set_visible(False)
    for ax, (env, episodes, every) in zip(axes.flat, panels, strict=False):
        mine = [r for r in records if (r["env"], r["demos_episodes"], r["demos_subsample"]) == (env, episodes, every)]
        shown: set[str] = set()
        for r in sorted(mine, key=lambda r: (_label(r), r["seed"])):
            if r["learner"] is None or not r["curve"]:
                continue
            lab = _label(r)
            steps, values = zip(*r["curve"], strict=True)
            ax.plot(np.asarray(steps) / 1000, values, color=colour[lab], lw=1.2, alpha=0.8,
                    label=None if lab in shown else lab)
            shown.add(lab)
        bc = [r["normalized_return"] for r in mine if r["learner"] is None and r.get("normalized_return") is not None]
        if bc:
            ax.axhline(float(np.median(bc)), color="k", ls="--", lw=1, label="BC (the VAE's policy), median")
        for level in (0.9, 0.95):
            ax.axhline(level, color="grey", ls=":", lw=0.8)
        setting = f"{episodes} trajector{'y' if episodes == 1 else 'ies'}"
        setting += f", every {every}th transition" if every and every > 1 else ", full"
        ax.set(title=f"{env}: {setting}", xlabel="env steps (thousands)", ylabel="normalised return",
               ylim=(-0.05, 1.15))
        ax.legend(fontsize=7, loc="lower right")
    fig.tight_layout()
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=110)
    plt.close(fig)


def _k(steps: float | None) -> str:
    return "" if steps is None else f"{steps / 1000:.0f}k"


def markdown(records: list[dict[str, Any]]) -> str:
    """The table of docs/results.md: one row per (env, setting, method, learner, start), seeds side by side."""
    head = ("| env | demonstrations | method | seeds | env steps | normalised return, median | "
            "mean over the window, median | first >= 0.9 / 0.95 | wall time per run |")
    lines = [head, "| " + " | ".join(["---"] * 9) + " |"]
    for (env, _, episodes, _, label), rs in _grouped(records, lambda r: (
            r["env"], -(r["demos_subsample"] or 1), r["demos_episodes"], r["learner"] or "",
            _label(r) if r["learner"] else "BC (the VAE's policy)")):
        rs = sorted(rs, key=lambda r: r["seed"])
        trained = rs[0]["learner"] is not None
        every = rs[0]["demos_subsample"] or 1
        setting = f"{episodes}, every {every}th" if every > 1 else f"{episodes}, full"
        vals = [r.get("normalized_return") for r in rs]
        finals = " / ".join("" if v is None else f"{v:.3f}" + (" (periodic)" if r.get("from_curve") else "")
                            for v, r in zip(vals, rs, strict=True))
        known = [v for v in vals if v is not None]
        median = f", **{float(np.median(known)):.3f}**" if len(known) > 1 else ""
        windows = [r.get("window_mean") for r in rs]
        inside = [w for w in windows if w is not None]
        window = (" / ".join("-" if w is None else f"{w:.3f}" for w in windows)
                  + (f", {float(np.median(inside)):.3f}" if len(inside) > 1 else "")) if inside else ""
        steps = " / ".join(_k(r["env_steps"]) for r in rs) if trained else "0"
        reach = ", ".join(f"{_k(r['steps_to_0.9']) or '-'} / {_k(r['steps_to_0.95']) or '-'}" for r in rs
                          ) if trained else ""
        walls = [r["wall_time_s"] for r in rs if r.get("wall_time_s")]
        lo, hi = (f"{min(walls) / 60:.0f}", f"{max(walls) / 60:.0f}") if walls else ("", "")
        wall = "" if not walls or not trained else f"{lo} min" if lo == hi else f"{lo}-{hi} min"
        seeds = " / ".join(str(r["seed"]) for r in rs)
        cells = [env, setting, label, seeds, steps, finals + median, window, reach, wall]
        lines.append("| " + " | ".join(cells) + " |")
    return "\n".join(lines) + "\n"


SUMMARY_COLUMNS = [(None, None, "BC (the VAE's policy)"), ("gail", "ppo", "GAIL + PPO"),
                   ("digail", "ppo", "Directed-Info GAIL + PPO"), ("gail", "sac", "GAIL + SAC"),
                   ("digail", "sac", "Directed-Info GAIL + SAC")]


def summary(records: list[dict[str, Any]], budget: float = 1e6) -> str:
    """The summary table (results page): one row per (env, demonstration setting), one column per method and
    learner, each cell the median over seeds of the final normalised return, with the env steps where the runs
    stopped short of the budget. Where a method was run from more than one start, the start with the most seeds
    stands for it."""
    names = " | ".join(c[2] for c in SUMMARY_COLUMNS)
    head = f"| env | demonstrations | {names} |"
    lines = [head, "| " + " | ".join(["---"] * (len(SUMMARY_COLUMNS) + 2)) + " |"]
    for (env, _, episodes), mine in _grouped(records, lambda r: (
            r["env"], -(r["demos_subsample"] or 1), r["demos_episodes"])):
        every = mine[0]["demos_subsample"] or 1
        cells = [env, f"{episodes}, every {every}th" if every > 1 else f"{episodes}, full"]
        for method, learner, _ in SUMMARY_COLUMNS:
            column = [r for r in mine if r["learner"] == learner and (learner is None or r["method"] == method)]
            starts = _grouped(column, lambda r: (r.get("policy_init"), r.get("bc_weight")))
            if not starts:
                cells.append("")
                continue
            rs = max((rs for _, rs in starts), key=len)
            vals = [r["normalized_return"] for r in rs if r.get("normalized_return") is not None]
            cell = f"{float(np.median(vals)):.3f}" if vals else ""
            steps = max(r["env_steps"] for r in rs)
            if learner is not None and steps < 0.99 * budget:
                cell += f" by {_k(steps)}"
            cells.append(cell)
        lines.append("| " + " | ".join(cells) + " |")
    return "\n".join(lines) + "\n"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("runs", nargs="*", type=Path)
    parser.add_argument("--sweep", type=Path)
    parser.add_argument("--out", type=Path, default=Path("benchmarks/results/few-demos/fewdemo.json"))
    parser.add_argument("--commands", type=Path, help="a JSON file {run folder: the command that made it}")
    parser.add_argument("--merge", action="store_true",
                        help="keep the entries of --out whose run folders are not given (runs made elsewhere)")
    parser.add_argument("--drop", nargs="*", default=[], metavar="RUN",
                        help="with --merge, remove these entries of --out (runs that longer runs continue)")
    parser.add_argument("--window", type=float, nargs=2, default=WINDOW, metavar=("FROM", "TO"),
                        help="env steps whose periodic evaluations are averaged to compare runs at the same steps")
    parser.add_argument("--figure", type=Path, help="draw the learning curves to this PNG")
    parser.add_argument("--markdown", type=Path, help="write the table of docs/results.md to this file")
    parser.add_argument("--summary", type=Path, help="write the summary table (medians only) to this file")
    args = parser.parse_args()
    if args.drop and not args.merge:
        parser.error("--drop removes entries kept by --merge; add --merge")
    runs = list(args.runs)
    if args.sweep is not None:
        runs += sorted(p.parent for p in args.sweep.glob("*/*/config.json"))
    records = [r for r in (summarise_run(p, tuple(args.window)) for p in runs) if r is not None]
    if args.commands is not None:
        commands = json.loads(args.commands.read_text())
        for r in records:
            r["command"] = commands.get(r["run"])
    if args.merge:
        stored = json.loads(args.out.read_text())["runs"] if args.out.is_file() else []
        unknown = set(args.drop) - {r["run"] for r in stored}
        if unknown:
            parser.error(f"--drop names runs that are not in {args.out}: {sorted(unknown)}")
        # A rerun takes its stored entry's place, so the file's order (and its diff) stays put.
        fresh = {r["run"]: r for r in records}
        records = [fresh.pop(r["run"], r) for r in stored if r["run"] not in args.drop] + list(fresh.values())
        for r in records:  # entries made before the window existed, or with another one
            if r.get("window") != list(args.window):
                r["window"] = list(args.window)
                r["window_mean"] = window_mean([(s, v) for s, v in r.get("curve", [])], tuple(args.window))
    result = {"partial": any(r.get("partial") for r in records), "runs": records, "table": table(records),
              "references": REFERENCES}
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(json.dumps(result, indent=1) + "\n")
    for row in result["table"]:
        print(row)
    if args.markdown is not None:
        args.markdown.write_text(markdown(records))
        print(f"wrote {args.markdown}")
    if args.summary is not None:
        args.summary.write_text(summary(records))
        print(f"wrote {args.summary}")
    if args.figure is not None:
        draw_curves(records, args.figure)
        print(f"drew {args.figure}")
    print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
