"""The paper's Table 2 (FetchPickAndPlace, five methods, three seeds) from the sweep that ran it.

    digail sweep --spec benchmarks/sweeps/table2.toml --out runs/sweeps/table2      the 15 trials (resumable)
    python benchmarks/table2.py runs/sweeps/table2

writes benchmarks/results/table2/table2.json (per method and seed: the paper's dense return, the sparse return, success,
grasp and lift rates, env steps, wall time, the exact commands; medians; the issue's targets), copies the median
seed's run folder of every method to benchmarks/results/runs/fetch_<method>_s<seed>/ and puts the Markdown table
into docs/results.md between its table2 markers. The sweep's own results.json / results.md go to
benchmarks/results/sweeps/table2/ as for the other published tables.
"""

from __future__ import annotations

import argparse
import json
import shutil
from pathlib import Path
from typing import Any

import numpy as np

from digail import paper
from digail.sweep.publish import publish_run, replace_between_markers

HERE = Path(__file__).resolve().parent
PAGE = HERE.parent / "docs" / "results.md"
OUT = HERE / "results" / "table2" / "table2.json"
RUNS = HERE / "results" / "runs"
MARKERS = ("<!-- table2:start (python benchmarks/table2.py SWEEP) -->", "<!-- table2:end -->")
ENV = "digail/FetchPickAndPlace-v4"
PAPER = {method: mean for method, (mean, _std) in paper.table("table2")[ENV].items()}
"""the paper's Table 2 (`digail/paper.toml`): mean dense return over 100 episodes (it reports no success rate)"""
NAMES = {"vae": "VAE", "gail": "GAIL", "digail": "Directed-Info GAIL", "gail-l2": "GAIL + L2",
         "digail-l2": "Directed-Info GAIL + L2"}
KEYS = ("mean_return", "std_return", "sparse_return", "success_rate", "grasp_rate", "lift_rate", "normalized_return")


def table(results: dict[str, Any]) -> dict[str, Any]:
    """Per method: every finished seed's measures and the medians; the benchmark's targets where decidable."""
    methods: dict[str, Any] = {}
    for method, rec in results["table"].get(ENV, {}).items():
        seeds = []
        for s in sorted(rec["seeds"].values(), key=lambda s: s["seed"]):
            if s["status"] != "done":
                continue
            m = s["metrics"]
            seeds.append({"seed": s["seed"], "run": s["run"], **{k: m.get(k) for k in KEYS},
                          "episodes": m.get("episodes"), "env_steps": s.get("env_steps"), "wall_s": s.get("wall_s"),
                          "vae_wall_s": s.get("vae_wall_s"), "commands": s.get("commands", [])})
        if not seeds:
            continue
        methods[method] = {
            "paper_dense_return": PAPER.get(method), "seeds": seeds, "complete": len(seeds) == 3,
            **{f"median_{k}": float(np.median([r[k] for r in seeds])) for k in KEYS if k != "std_return"
               and all(r[k] is not None for r in seeds)},
        }
    out: dict[str, Any] = {"env_id": ENV, "sweep": results["name"], "methods": methods}
    best, base = methods.get("digail-l2"), methods.get("gail-l2")
    if best is not None:
        out["targets"] = {
            "digail_l2_success_median_at_least_0.5": best["median_success_rate"] >= 0.5,
            "digail_l2_success_at_least_gail_l2": (None if base is None
                                                    else best["median_success_rate"] >= base["median_success_rate"]),
            "digail_l2_dense_better_than_paper": best["median_mean_return"] > PAPER["digail-l2"],
            "complete": best["complete"] and (base is not None and base["complete"]),
        }
    return out


def markdown(t: dict[str, Any]) -> str:
    lines = ["| method | paper: dense return | dense return (median seed) | success rate, per seed | grasp rate, "
             "per seed | lift rate, per seed | sparse return, median | env steps | seeds |",
             "| --- | --- | --- | --- | --- | --- | --- | --- | --- |"]
    for method in NAMES:
        rec = t["methods"].get(method)
        if rec is None:
            continue
        seeds = rec["seeds"]
        mid = sorted(seeds, key=lambda r: r["mean_return"])[(len(seeds) - 1) // 2]

        rates = [" / ".join(f"{r[key]:.2f}" for r in seeds) for key in ("success_rate", "grasp_rate", "lift_rate")]
        lines.append(f"| {NAMES[method]} | {PAPER[method]:.2f} | {mid['mean_return']:.2f} +- {mid['std_return']:.2f} "
                     f"| {' | '.join(rates)} | {rec['median_sparse_return']:.2f} "
                     f"| {(mid['env_steps'] or 0) / 1e3:.0f}k | {len(seeds)} of 3 |")
    return "\n".join(lines)


def publish(t: dict[str, Any], sweep: Path) -> list[str]:
    """The median seed's run folder per method (small files only) under benchmarks/results/runs/."""
    done = []
    for method, rec in t["methods"].items():
        mid = sorted(rec["seeds"], key=lambda r: r["mean_return"])[(len(rec["seeds"]) - 1) // 2]
        dest = RUNS / f"fetch_{method}_s{mid['seed']}"
        publish_run(sweep / mid["run"], dest)
        done.append(str(dest.relative_to(HERE.parent)))
    return done


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("sweep", type=Path, help="the Table 2 sweep folder (with results.json)")
    args = ap.parse_args()
    results = json.loads((args.sweep / "results.json").read_text())
    t = table(results)
    OUT.write_text(json.dumps(t, indent=1) + "\n")
    committed = HERE / "results" / "sweeps" / results["name"]
    committed.mkdir(parents=True, exist_ok=True)
    for name in ("results.json", "results.md"):
        shutil.copyfile(args.sweep / name, committed / name)
    print("\n".join(publish(t, args.sweep)))
    md = markdown(t)
    replace_between_markers(PAGE, MARKERS, md)
    print(md)
    print(json.dumps(t.get("targets", {}), indent=1))


if __name__ == "__main__":
    main()
