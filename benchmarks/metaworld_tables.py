"""The Meta-World tables of docs/results.md, from the published JSON files under benchmarks/results/.

    python benchmarks/metaworld_tables.py

prints the segmentation table (the Meta-World rows of segmentation.json with their auto-K choice from
segmentation_codes_metaworld.json), the cross-task table (metaworld_shared.json) and the few-demonstration screen
(metaworld_fewdemo.json: one seed a cell as success rate and mean episode length, several as the median success
rate and each seed's).
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

RESULTS = Path(__file__).resolve().parent / "results"


def segmentation() -> str:
    tasks = json.loads((RESULTS / "segmentation.json").read_text())["tasks"]
    codes_file = RESULTS / "segmentation_codes_metaworld.json"
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


def fewdemo() -> str:
    rows = json.loads((RESULTS / "metaworld_fewdemo.json").read_text())["rows"]
    names = {"bc": "BC, the VAE's policy (K = phases)", "flatbc": "flat BC (K = 1)",
             "digail-l2": "Directed-Info GAIL + L2 from BC", "flatbc-l2": "GAIL + L2 from flat BC"}
    # the adversarial methods once per training length (`iterations`, PPO iterations of 4096 env steps)
    methods = [("bc", None), ("flatbc", None)] + sorted(
        {(r["method"], r["iterations"]) for r in rows if r["method"].endswith("-l2")}, key=lambda m: (m[1], m[0]))
    tasks = list(dict.fromkeys(r["task"] for r in rows))
    lines = ["| method | " + " | ".join(tasks) + " |", "| --- |" + " --- |" * len(tasks)]
    for m, iterations in methods:
        cells = []
        for t in tasks:
            got = sorted((r for r in rows if r["task"] == t and r["method"] == m
                          and r.get("iterations") == iterations), key=lambda r: r["seed"])
            if not got:
                cells.append("-")
            elif len(got) == 1:
                cells.append(f"{got[0]['success_rate']:.2f} ({got[0]['mean_length']:.0f} steps)")
            else:  # the median over seeds, then each seed's
                rates = [r["success_rate"] for r in got]
                cells.append(f"{np.median(rates):.2f} ({' / '.join(f'{v:.2f}' for v in rates)})")
        if any(c != "-" for c in cells):
            steps = f", {iterations} iterations ({round(iterations * 4096 / 1000)}k env steps)" if iterations else ""
            label = names[m] + steps
            lines.append(f"| {label} | " + " | ".join(cells) + " |")
    return "\n".join(lines)


if __name__ == "__main__":
    print(segmentation(), shared(), fewdemo(), sep="\n\n")
