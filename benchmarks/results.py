"""Result tables: run the CLI for several seeds and collect what `digail evaluate / segment / compose` wrote.

    python benchmarks/results.py fourrooms    [--seeds 0 1 2] [--episodes 300]
    python benchmarks/results.py circleworld  [--seeds 0 1 2] [--episodes 300]

Each seed runs exactly what a user would type (printed as it goes):
    digail pretrain --demos D --seed S --out R/vae_sS
    digail evaluate R/vae_sS --episodes N                      (the VAE behaviour-cloning baseline)
    digail train --method digail --demos D --vae R/vae_sS --seed S --out R/digail_sS
    digail evaluate R/digail_sS --episodes N
and on Circle-World also plain GAIL and `digail compose R/digail_sS --schedule 1:60,0:60`.
Writes benchmarks/results/<name>.json with every seed's numbers and their medians.
"""

from __future__ import annotations

import argparse
import json
import shlex
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np

HERE = Path(__file__).resolve().parent
DIGAIL = [sys.executable, "-m", "digail.cli"]

TASKS = {
    "fourrooms": dict(env="digail/FourRooms-v0", demos="digail/fourrooms/expert-v0", gail=False, compose=None),
    "circleworld": dict(env="digail/CircleWorld-v0", demos="digail/circleworld/expert-v0", gail=True,
                        compose="1:60,0:60"),
}


def sh(args: list[str]) -> None:
    print("$ digail " + " ".join(shlex.quote(a) for a in args), flush=True)
    t0 = time.perf_counter()
    subprocess.run([*DIGAIL, *args], check=True, stdout=subprocess.DEVNULL)
    print(f"  ({time.perf_counter() - t0:.0f}s)", flush=True)


def load(path: Path) -> dict[str, Any]:
    return json.loads(path.read_text())


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("task", choices=sorted(TASKS))
    parser.add_argument("--seeds", type=int, nargs="+", default=[0, 1, 2])
    parser.add_argument("--episodes", type=int, default=300)
    parser.add_argument("--root", default="runs/results")
    args = parser.parse_args()
    task = TASKS[args.task]
    root = Path(args.root) / args.task
    per_seed: dict[str, dict[str, Any]] = {}
    for seed in args.seeds:
        rec: dict[str, Any] = {}
        vae, dig, gail = root / f"vae_s{seed}", root / f"digail_s{seed}", root / f"gail_s{seed}"
        if not (vae / "model.pt").exists():
            sh(["pretrain", "--demos", task["demos"], "--seed", str(seed), "--out", str(vae), "--force"])
        sh(["evaluate", str(vae), "--episodes", str(args.episodes)])
        rec["segmentation"] = load(vae / "segmentation.json")
        rec["vae"] = load(vae / "eval.json")
        rec["vae_time_s"] = load(vae / "config.json").get("train_time_s")
        if not (dig / "model.pt").exists():
            sh(["train", "--method", "digail", "--demos", task["demos"], "--vae", str(vae), "--seed", str(seed),
                "--out", str(dig), "--force"])
        sh(["evaluate", str(dig), "--episodes", str(args.episodes)])
        rec["digail"] = load(dig / "eval.json")
        if task["compose"]:
            sh(["compose", str(dig), "--schedule", task["compose"], "--episodes", "100"])
            rec["compose"] = load(dig / "compose.json")
        if task["gail"]:
            if not (gail / "model.pt").exists():
                sh(["train", "--method", "gail", "--demos", task["demos"], "--seed", str(seed), "--out", str(gail),
                    "--force"])
            sh(["evaluate", str(gail), "--episodes", str(args.episodes)])
            rec["gail"] = load(gail / "eval.json")
        per_seed[str(seed)] = rec
    summary = summarize(per_seed)
    out = HERE / "results" / f"{args.task}.json"
    out.parent.mkdir(exist_ok=True)
    out.write_text(json.dumps({"task": args.task, "env": task["env"], "seeds": args.seeds,
                               "episodes": args.episodes, "median": summary, "per_seed": per_seed},
                              indent=2, default=str) + "\n")
    print(json.dumps(summary, indent=2))


def summarize(per_seed: dict[str, dict[str, Any]]) -> dict[str, dict[str, float]]:
    """Median over seeds of every numeric field, per section."""
    out: dict[str, dict[str, float]] = {}
    sections = {k for rec in per_seed.values() for k, v in rec.items() if isinstance(v, dict)}
    for sec in sorted(sections):
        keys = {k for rec in per_seed.values() for k, v in rec.get(sec, {}).items()
                if isinstance(v, int | float) and not isinstance(v, bool)}
        out[sec] = {k: float(np.median([rec[sec][k] for rec in per_seed.values() if k in rec.get(sec, {})]))
                    for k in sorted(keys)}
    return out


if __name__ == "__main__":
    main()
