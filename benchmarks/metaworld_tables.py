"""The Meta-World tables of docs/results.md, from the published JSON files under benchmarks/results/.

    python benchmarks/metaworld_tables.py [--figure benchmarks/results/figures/metaworld_fewdemo.png]

prints the segmentation table (the Meta-World rows of segmentation.json with their auto-K choice from
segmentation_codes_metaworld.json), the cross-task table (metaworld_shared.json) and the few-demonstration screen
(metaworld_fewdemo.json: one seed a cell as success rate and mean episode length, several as the median success
rate and each seed's). With --figure, also draws the few-demonstration learning curves (success against env
steps, the seeds' median) and, over training, D's accuracy on the expert's steps and the reward per agent step.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

RESULTS = Path(__file__).resolve().parent / "results" / "metaworld"
SEGMENTATION = Path(__file__).resolve().parent / "results" / "segmentation"
# the shipped tasks in the order of the segmentation table and the how-to
ORDER = ("pick-place", "assembly", "stick-pull", "shelf-place", "basketball", "disassemble", "peg-insert-side",
         "box-close", "hammer")


def segmentation() -> str:
    tasks = json.loads((SEGMENTATION / "segmentation.json").read_text())["tasks"]
    codes_file = SEGMENTATION / "segmentation_codes_metaworld.json"
    auto = json.loads(codes_file.read_text())["tasks"] if codes_file.is_file() else {}
    lines = ["| task | K (phases) | steps | accuracy (seeds) | NMI | boundary F1 | switches / episode (truth) | "
             "auto-K, seed 0 | time |", "| --- | --- | --- | --- | --- | --- | --- | --- | --- |"]
    hits = passes = 0
    for name, task in tasks.items():
        if not name.startswith("metaworld-"):
            continue
        m = task["median"]
        accs = " / ".join(f"{r['accuracy']:.2f}" for r in task["seeds"])
        acc = f"**{m['accuracy']:.3f}**" if m["accuracy"] >= 0.9 else f"{m['accuracy']:.3f}, missed"
        passes += m["accuracy"] >= 0.9
        chosen = "-"
        if name in auto:
            row = auto[name]["seeds"][0]
            hits += row["hit"]
            chosen = f"**{row['chosen']}**" if row["hit"] else f"{row['chosen']}, missed"
        lines.append(f"| {name.removeprefix('metaworld-')} | {task['codes']} | {task['seeds'][0]['steps']} | {acc} "
                     f"({accs}) | {m['nmi']:.2f} | {m['boundary_f1']:.2f} | {m['switches_per_episode']:.2f} "
                     f"({m['true_switches_per_episode']:.2f}) | {chosen} | {m['time_s']:.0f} s |")
    lines.append(f"\naccuracy >= 0.9 on {passes} tasks; auto-K equal to the phase count on {hits} of {len(auto)}")
    return "\n".join(lines)


def shared() -> str:
    result = json.loads((RESULTS / "metaworld_shared.json").read_text())
    seeds = result["seeds"]
    tasks = list(seeds[0]["tasks"])
    lines = ["| | " + " | ".join(tasks) + " | all three |", "| --- |" + " --- |" * (len(tasks) + 1)]
    for key, what in (("shared", "accuracy, one code -> kind matching for all tasks"),
                      ("own", "accuracy, each task's own matching"), ("nmi", "NMI")):
        cells = []
        for t in tasks:
            vals = [s["tasks"][t][key] for s in seeds]
            cells.append(f"{np.median(vals):.3f} ({' / '.join(f'{v:.2f}' for v in vals)})")
        total = (f"{np.median([s['accuracy'] for s in seeds]):.3f}" if key == "shared" else "")
        lines.append(f"| {what} | " + " | ".join(cells) + f" | {total} |")
    return "\n".join(lines)


def _cell(rows: list[dict], task: str, method: str, iterations: int | None) -> tuple[str, float | None]:
    got = sorted((r for r in rows if r["task"] == task and r["method"] == method
                  and r.get("iterations") == iterations), key=lambda r: r["seed"])
    if not got:
        return "-", None
    rates = [r["success_rate"] for r in got]
    if len(rates) == 1:
        return f"{rates[0]:.2f} (one seed)", rates[0]
    median = float(np.median(rates))
    return f"{median:.2f} ({' / '.join(f'{v:.2f}' for v in rates)})", median


def _lead(a: float | None, b: float | None) -> str:
    if a is None or b is None:
        return "-"
    lead = round(a - b, 2)  # success rates are hundredths: 0.86 - 0.66 is a lead of 0.20, not 0.1999...
    return f"**{lead:+.2f}**" if lead >= 0.2 else f"{lead:+.2f}"


def fewdemo() -> str:
    """Two tables: behaviour cloning with and without codes on every task, then the adversarial methods from those
    starts, once per training length (the seeds' median success, then each seed's)."""
    from digail.envs.metaworld import phase_counts

    rows = json.loads((RESULTS / "metaworld_fewdemo.json").read_text())["rows"]
    tasks = sorted(dict.fromkeys(r["task"] for r in rows), key=lambda t: ORDER.index(t) if t in ORDER else 99)
    lines = ["| task | phases | BC, the VAE's policy (K = phases) | flat BC (K = 1) | codes' lead |",
             "| --- | --- | --- | --- | --- |"]
    for t in tasks:
        bc, a = _cell(rows, t, "bc", None)
        flat, b = _cell(rows, t, "flatbc", None)
        lines.append(f"| {t} | {phase_counts()[f'{t}-v3']} | {bc} | {flat} | {_lead(a, b)} |")
    budgets = sorted({r["iterations"] for r in rows if "-l2" in r["method"]})
    for iterations in budgets:
        lines += ["", f"{iterations} PPO iterations ({iterations * 4096:,} env steps):", "",
                  "| task | Directed-Info GAIL + L2 from BC | GAIL + L2 from flat BC | Directed-Info GAIL + L2, D's "
                  "inputs noised | lead of Directed-Info GAIL + L2 |",
                  "| --- | --- | --- | --- | --- |"]
        for t in tasks:
            di, a = _cell(rows, t, "digail-l2", iterations)
            flat, b = _cell(rows, t, "flatbc-l2", iterations)
            noised, _ = _cell(rows, t, "digail-l2-noise", iterations)
            if a is None and b is None:
                continue
            lines.append(f"| {t} | {di} | {flat} | {noised} | {_lead(a, b)} |")
    return "\n".join(lines)


STYLE = {"bc": ("tab:blue", "BC (K = phases)"), "flatbc": ("tab:gray", "flat BC"),
         "digail-l2": ("tab:blue", "Directed-Info GAIL + L2"), "flatbc-l2": ("tab:gray", "GAIL + L2 (flat)"),
         "digail-l2-noise": ("tab:orange", "Directed-Info GAIL + L2, D noised")}


def figure(path: Path) -> None:
    """Per task: success against env steps (the seeds' median, the BC start at 0), D's expert accuracy and the
    reward per agent step over training (the seeds' median of the longest runs)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    rows = json.loads((RESULTS / "metaworld_fewdemo.json").read_text())["rows"]
    trained = [r for r in rows if "-l2" in r["method"] and r.get("iterations")]
    tasks = list(dict.fromkeys(r["task"] for r in trained))
    fig, axes = plt.subplots(3, len(tasks), figsize=(3.2 * len(tasks), 8), squeeze=False, sharex="row")
    for col, task in enumerate(tasks):
        ax_s, ax_d, ax_r = axes[:, col]
        for method in ("digail-l2", "flatbc-l2", "digail-l2-noise"):
            color, label = STYLE[method]
            start = "flatbc" if method.startswith("flatbc") else "bc"
            points = [(0, np.median([r["success_rate"] for r in rows if r["task"] == task
                                     and r["method"] == start]))]
            its = sorted({r["iterations"] for r in trained if r["task"] == task and r["method"] == method})
            for it in its:
                points.append((it * 4096, np.median([r["success_rate"] for r in trained if r["task"] == task
                                                     and r["method"] == method and r["iterations"] == it])))
            if len(points) > 1:
                x, y = zip(*points, strict=True)
                ax_s.plot(x, y, marker="o", color=color, label=label, ls="--" if method.endswith("noise") else "-")
            longest = [r for r in trained if r["task"] == task and r["method"] == method
                       and r["iterations"] == (its[-1] if its else None) and r.get("per_iteration")]
            for ax, key in ((ax_d, "disc_acc_expert"), (ax_r, "disc_reward")):
                curves = [r["per_iteration"][key] for r in longest]
                if curves:
                    n = min(len(c) for c in curves)
                    med = np.nanmedian(np.array([[np.nan if v is None else v for v in c[:n]] for c in curves]),
                                       axis=0)
                    ax.plot(np.arange(1, n + 1) * 4096, med, color=color, lw=1,
                            ls="--" if method.endswith("noise") else "-")
        ax_s.set_title(task)
        ax_s.set_ylim(-0.02, 1.02)
        ax_d.set_ylim(0.4, 1.02)
        ax_r.set_xlabel("env steps")
    axes[0, 0].set_ylabel("success (median of 3 seeds)")
    axes[1, 0].set_ylabel("D's accuracy on expert steps")
    axes[2, 0].set_ylabel("reward per agent step (log D)")
    axes[0, 0].legend(fontsize=7)
    fig.suptitle("Meta-World, 10 demonstrations: success (0 env steps = the BC start) and what D teaches")
    fig.tight_layout()
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=110)


if __name__ == "__main__":
    import argparse

    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--figure", type=Path, help="also draw the few-demonstration curves to this PNG")
    args = parser.parse_args()
    print(segmentation(), shared(), fewdemo(), sep="\n\n")
    if args.figure:
        figure(args.figure)
