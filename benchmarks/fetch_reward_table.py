"""Few-demonstration Fetch at the full budget, by reward: seeds of 1M env steps for each row (three, or one where a
variant was screened), today's reward beside the others, each from the sub-task VAE and from the flat
behaviour-cloned start.

    benchmarks/fetch_fewdemo.sh 4 digail-l2-rel-argmax-noise-1m SEED      # SEED 0, 1, 2; and so on for each row:
    benchmarks/fetch_fewdemo.sh 4 flatbc-l2-rel-noise-1m SEED              # DEMOS 4 or 1, METHOD the row's key
    python benchmarks/fetch_reward_table.py runs/fetchfew \
        --out benchmarks/results/fetch-few-demos/fetch_reward_full.json \
        --figure benchmarks/results/figures/fetch_reward_full.png --page docs/results.md

Today's rows (`digail-l2-rel-argmax-1m`, `flatbc-l2-rel-1m`) are read from their run folders where this machine
has them, else from the few-demonstration study's results file
(`benchmarks/results/fetch-few-demos/fetch_fewdemo.json`), where
they were measured; any other row missing here keeps its record from `--out`. Per row: the success of each seed
(100 evaluation episodes at the end) and their median, grasp and lift, and whether the reward still taught at the
end: D's expert accuracy and the reward per agent step over the last 10 iterations.
"""

from __future__ import annotations

import argparse
import csv
import json
from pathlib import Path
from typing import Any

import numpy as np
from fetch_fewdemo import md_head, record

RELABEL_DI = "Directed-Info GAIL + L2, D's inputs noised (sigma 0.15), its expert goals relabelled (4 copies)"
RELABEL_FLAT = "GAIL + L2 from flat BC, D's inputs noised (sigma 0.15), its expert goals relabelled (4 copies)"
ROWS = {
    "digail-l2-rel-argmax-1m": "Directed-Info GAIL + L2, D by cross-entropy (today's)",
    "flatbc-l2-rel-1m": "GAIL + L2 from flat BC, D by cross-entropy (today's)",
    "digail-l2-rel-argmax-noise-1m": "Directed-Info GAIL + L2, D's inputs noised (sigma 0.15)",
    "flatbc-l2-rel-noise-1m": "GAIL + L2 from flat BC, D's inputs noised (sigma 0.15)",
    "digail-l2-rel-argmax-noise5-1m": "Directed-Info GAIL + L2, D's inputs noised (sigma 0.5)",
    "flatbc-l2-rel-noise5-1m": "GAIL + L2 from flat BC, D's inputs noised (sigma 0.5)",
    "digail-l2-rel-argmax-noise-relabel-1m": RELABEL_DI,
    "flatbc-l2-rel-noise-relabel-1m": RELABEL_FLAT,
}
"""method of `fetch_fewdemo.sh` -> the row's name, in the table's order (4 demonstrations)"""
ROWS_ONE = {
    "digail-l2-rel": "Directed-Info GAIL + L2, D by cross-entropy (today's, 410k env steps)",
    "flatbc-l2-rel": "GAIL + L2 from flat BC, D by cross-entropy (today's, 410k env steps)",
    "digail-l2-rel-argmax-noise-1m": "Directed-Info GAIL + L2, D's inputs noised (sigma 0.15)",
    "flatbc-l2-rel-noise-1m": "GAIL + L2 from flat BC, D's inputs noised (sigma 0.15)",
    "digail-l2-rel-argmax-noise-relabel-1m": RELABEL_DI,
    "flatbc-l2-rel-noise-relabel-1m": RELABEL_FLAT,
}
"""the same with 1 demonstration: today's rows are the study's (3 seeds at 410k), the others at 1M"""
TABLES = {4: ROWS, 1: ROWS_ONE}
SEEDS = (0, 1, 2)
STUDY = Path(__file__).resolve().parent / "results" / "fetch-few-demos" / "fetch_fewdemo.json"


def collect(root: Path, kept: list[dict[str, Any]], demos: int = 4) -> list[dict[str, Any]]:
    """Every (row, seed) record: from its run folder when it has been evaluated, else the one in `kept`."""
    earlier = {(r["method"], r["seed"]): r for r in kept if r.get("demos") == demos}
    out = []
    for method in TABLES[demos]:
        for seed in SEEDS:
            run = root / f"d{demos}" / f"{method}_s{seed}"
            if (run / "eval.json").is_file():
                out.append(record(run))
            elif (method, seed) in earlier:
                out.append(earlier[(method, seed)])
    return out


def table(records: list[dict[str, Any]], demos: int = 4) -> list[dict[str, Any]]:
    rows = []
    for method, label in TABLES[demos].items():
        done = [r for r in records if r["method"] == method and r.get("status") == "done"
                and r.get("demos", demos) == demos]
        if not done:
            continue
        med = {k: float(np.median([r[k] for r in done])) for k in ("success_rate", "grasp_rate", "lift_rate")}
        late = {k: float(np.median([r[k] for r in done if r.get(k) is not None]))
                for k in ("late_disc_acc_expert", "late_disc_reward") if any(r.get(k) is not None for r in done)}
        rows.append({"method": method, "label": label, "seeds": [r["seed"] for r in done],
                     "per_seed_success_rate": [r["success_rate"] for r in done],
                     **{f"median_{k}": v for k, v in med.items()}, **{f"median_{k}": v for k, v in late.items()},
                     "env_steps": max(r["env_steps"] for r in done)})
    return rows


def markdown(rows: list[dict[str, Any]]) -> str:
    lines = md_head(["start and reward", "success, per seed (median)", "grasp", "lift",
                     "D's expert accuracy, last 10 iterations", "reward per agent step, last 10 iterations",
                     "env steps"])
    for r in rows:
        per = " / ".join(f"{v:.2f}" for v in r["per_seed_success_rate"])
        acc, rew = r.get("median_late_disc_acc_expert"), r.get("median_late_disc_reward")
        lines.append(f"| {r['label']} | {per} (**{r['median_success_rate']:.2f}**) | {r['median_grasp_rate']:.2f} | "
                     f"{r['median_lift_rate']:.2f} | {'-' if acc is None else f'{acc:.2f}'} | "
                     f"{'-' if rew is None else f'{rew:.3f}'} | {r['env_steps'] / 1000:.0f}k |")
    return "\n".join(lines) + "\n"


COMMITTED = Path(__file__).resolve().parent / "results" / "runs"


def median_seed_run(root: Path, records: list[dict[str, Any]], method: str) -> Path | None:
    """The run folder of the row's median seed (by success): on this machine, or committed as
    `benchmarks/results/runs/fetch4_<method>_s<seed>`."""
    done = sorted((r for r in records if r["method"] == method and r.get("status") == "done"),
                  key=lambda r: r["success_rate"])
    if not done:
        return None
    seed = done[len(done) // 2]["seed"]
    for run in (root / "d4" / f"{method}_s{seed}", COMMITTED / f"fetch4_{method}_s{seed}"):
        if (run / "metrics.csv").is_file():
            return run
    return None


def disc_curve(run: Path, every: int = 5) -> list[tuple[float, float, float]]:
    """(env step, D's expert accuracy, reward per agent step) of every `every`-th training iteration."""
    with (run / "metrics.csv").open() as f:
        rows = [r for r in csv.DictReader(f) if r.get("disc/acc_expert") and r.get("rollout/disc_reward")]
    return [(float(r["step"]), float(r["disc/acc_expert"]), float(r["rollout/disc_reward"])) for r in rows[::every]]


def figure(records: list[dict[str, Any]], path: Path, root: Path) -> None:
    """Left: each row's learning curves, one thin line per seed and the median over seeds (20-episode evaluations).
    Middle and right: over training, D's expert accuracy and the reward per agent step of the row's median seed."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, (ax, ax_acc, ax_rew) = plt.subplots(1, 3, figsize=(15, 5.6))
    for i, method in enumerate(ROWS):
        run = median_seed_run(root, records, method)
        if run is None:
            continue
        steps, acc, rew = zip(*disc_curve(run), strict=True)
        ax_acc.plot([s / 1e3 for s in steps], acc, color=f"C{i}", lw=1.2)
        ax_rew.plot([s / 1e3 for s in steps], rew, color=f"C{i}", lw=1.2)
    ax_acc.set_title("D's expert accuracy (median seed)")
    ax_rew.set_title("reward per agent step (median seed)")
    ax_rew.set_yscale("log")
    for a in (ax_acc, ax_rew):
        a.set_xlabel("env steps (thousands)")
    for i, (method, label) in enumerate(ROWS.items()):
        curves = [r["curve"] for r in records if r["method"] == method and r.get("curve")]
        if not curves:
            continue
        color = f"C{i}"
        for c in curves:
            ax.plot([s / 1e3 for s, _ in c], [v for _, v in c], color=color, alpha=0.25, lw=0.8)
        n = min(len(c) for c in curves)
        steps = [s / 1e3 for s, _ in curves[0][:n]]
        ax.plot(steps, np.median([[v for _, v in c[:n]] for c in curves], axis=0), color=color, lw=2, label=label)
    ax.set_xlabel("env steps (thousands)")
    ax.set_ylabel("success (20 episodes)")
    ax.set_title("success, 4 demonstrations (median; thin: each seed)")
    ax.set_ylim(-0.02, 1.02)
    fig.tight_layout(rect=(0, 0.22, 1, 1))  # the rows' legend below the panels, where it hides no curve
    fig.legend(*ax.get_legend_handles_labels(), loc="lower center", ncol=2, fontsize=8, frameon=False)
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=110)
    plt.close(fig)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("root", type=Path, help="the folder holding d4/<method>_s<seed> run folders")
    parser.add_argument("--out", type=Path, default=Path("benchmarks/results/fetch-few-demos/fetch_reward_full.json"))
    parser.add_argument("--figure", type=Path)
    parser.add_argument("--page", type=Path, help="a page with the table's markers, rewritten in place")
    args = parser.parse_args()
    kept = json.loads(STUDY.read_text())["runs"]
    if args.out.is_file():
        kept = [*kept, *json.loads(args.out.read_text())["runs"]]
    records = collect(args.root, kept)
    rows = table(records)
    one_records = collect(args.root, kept, demos=1)
    one_rows = table(one_records, demos=1)
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(json.dumps({"env_id": "digail/FetchPickAndPlace-v4", "rows": TABLES, "table": rows,
                                    "table_one_demonstration": one_rows, "runs": records + one_records},
                                   indent=1) + "\n")
    print(markdown(rows))
    print(markdown(one_rows))
    if args.page is not None:
        text = args.page.read_text()
        for name, body in (("fetch_reward_full", markdown(rows)), ("fetch_reward_full_one", markdown(one_rows))):
            start, end = f"<!-- {name}:start -->\n", f"<!-- {name}:end -->"
            a, b = text.index(start) + len(start), text.index(end)
            text = text[:a] + body + text[b:]
        args.page.write_text(text)
    if args.figure is not None:
        figure(records, args.figure, args.root)


if __name__ == "__main__":
    main()
