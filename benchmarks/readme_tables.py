"""The README's Four Rooms and Circle-World tables, cell for cell, from the sweeps that measured them.

    digail sweep --spec benchmarks/sweeps/results-fourrooms.toml --out runs/sweeps/results-fourrooms
    digail sweep --spec benchmarks/sweeps/results-circleworld.toml --out runs/sweeps/results-circleworld
    python benchmarks/readme_tables.py runs/sweeps/results-fourrooms runs/sweeps/results-circleworld

prints the Markdown tables (cells list seeds 0 / 1 / 2) and copies each sweep's `results.json` and `results.md`
to benchmarks/results/sweeps/<name>/, which is what the README quotes. `digail sweep` writes medians and quartiles;
the README shows every seed because three seeds are too few for quartiles to say much.
"""

from __future__ import annotations

import argparse
import json
import shutil
from pathlib import Path
from typing import Any

HERE = Path(__file__).resolve().parent
COMMITTED = HERE / "results" / "sweeps"

# (method, row title); then (metric key in the sweep's per-seed metrics, column title, number format)
TABLES: dict[str, dict[str, Any]] = {
    "digail/FourRooms-v0": {
        "rows": [("vae", "VAE after the polish (DI-GAIL's initialisation)"),
                 ("digail", "Directed-Info GAIL (preset)")],
        "cols": [("success_rate", "success rate", ".3f"), ("path_length_ratio", "path-length ratio", ".3f"),
                 ("normalized_return", "normalised return", ".3f")],
    },
    "digail/CircleWorld-v0": {
        "rows": [("vae", "VAE after the polish (DI-GAIL's initialisation)"),
                 ("digail", "Directed-Info GAIL (preset)"),
                 ("digail-l2", "Directed-Info GAIL + L2 (`--train.bc-weight 100`)"),
                 ("gail", "GAIL (`--method gail --train.ppo.policy-lr 3e-4 --train.anchor-weight 0`, one code)")],
        "cols": [("order_correct_rate", "order_correct", ".3f"), ("radius_error", "radius_error", ".3f"),
                 ("closure_error", "closure_error", ".2f"), ("mean_return", "mean return", ".0f")],
        "compose": {
            "rows": [("vae", "sub-task policies of the VAE"), ("digail", "sub-task policies of Directed-Info GAIL")],
            "cols": [("compose/order_reversed_rate", "order_reversed", ".3f"),
                     ("compose/radius_error", "radius_error", ".3f")],
            "title": "composed, schedule counter-clockwise:60 then clockwise:60",
        },
    },
}


def _cells(rec: dict[str, Any], key: str, fmt: str) -> str:
    seeds = sorted(rec["seeds"].values(), key=lambda s: s["seed"])
    vals = [s["metrics"].get(key) for s in seeds if s["status"] == "done"]
    return " / ".join("n/a" if v is None else format(v, fmt) for v in vals)


def _table(env_rec: dict[str, Any], rows: list[tuple[str, str]], cols: list[tuple[str, str, str]],
           first: str = "model") -> list[str]:
    out = [f"| {first} | " + " | ".join(c[1] for c in cols) + " |", "| --- " * (len(cols) + 1) + "|"]
    for method, title in rows:
        if method in env_rec:
            out.append(f"| {title} | " + " | ".join(_cells(env_rec[method], k, f) for k, _, f in cols) + " |")
    return out


def tables(results: dict[str, Any]) -> str:
    lines: list[str] = []
    for env, env_rec in results["table"].items():
        spec = TABLES.get(env)
        if spec is None:
            continue
        lines += [f"{env} (`{results['name']}`):", "", *_table(env_rec, spec["rows"], spec["cols"]), ""]
        if "compose" in spec:
            c = spec["compose"]
            lines += [*_table(env_rec, c["rows"], c["cols"], first=c["title"]), ""]
        vae_seeds = sorted(env_rec.get("vae", {}).get("seeds", {}).values(), key=lambda s: s["seed"])
        segs = [s["metrics"] for s in vae_seeds if "seg/accuracy" in s["metrics"]]
        if segs:
            lines.append("segmentation of the demonstrations (VAE runs): accuracy "
                         + " / ".join(f"{m['seg/accuracy']:.3f}" for m in segs) + ", NMI "
                         + " / ".join(f"{m['seg/nmi']:.3f}" for m in segs) + ", switches per episode "
                         + " / ".join(f"{m['seg/switches_per_episode']:.2f}" for m in segs))
            lines.append("")
    return "\n".join(lines)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("sweeps", nargs="+", type=Path, help="sweep folders (each with results.json)")
    args = ap.parse_args()
    for sweep in args.sweeps:
        results = json.loads((sweep / "results.json").read_text())
        dest = COMMITTED / results["name"]
        dest.mkdir(parents=True, exist_ok=True)
        for name in ("results.json", "results.md"):
            shutil.copyfile(sweep / name, dest / name)
        print(tables(results))


if __name__ == "__main__":
    main()
