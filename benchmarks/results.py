"""Result tables: run the CLI for several seeds and collect what `digail evaluate / segment / compose` wrote.

    python benchmarks/results.py fourrooms    [--seeds 0 1 2] [--episodes 300]
    python benchmarks/results.py circleworld  [--seeds 0 1 2] [--episodes 300]
    python benchmarks/results.py circleworld  --seeds 1 --only-seeds     (one seed's runs; no table written)

Each seed runs exactly what a user would type (printed as it goes):
    digail pretrain --demos D --seed S --out R/vae_sS
    digail evaluate R/vae_sS --episodes N                      (the VAE behaviour-cloning baseline)
    digail train --method digail --demos D --vae R/vae_sS --seed S --out R/digail_sS
    digail evaluate R/digail_sS --episodes N
and on Circle-World also Directed-Info GAIL + L2 (`--bc-weight 100`), plain GAIL (`--method gail`, with the
paper's policy learning rate `--train.ppo.policy-lr 3e-4` and no anchor `--train.anchor-weight 0`, since it trains
a fresh policy), and
`digail compose RUN --schedule <ccw>:60,<cw>:60` on the VAE and DI-GAIL runs, where <ccw> and <cw> are the codes
the VAE's segmentation matched to the counter-clockwise and clockwise labels (code ids are arbitrary).
Finished runs are reused, so seeds can run in parallel (`--only-seeds`) and a final call collects them.
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

from digail.envs.registry import env_spec
from digail.eval.composition import schedule_in_codes

HERE = Path(__file__).resolve().parent
DIGAIL = [sys.executable, "-m", "digail.cli"]

TASKS = {
    "fourrooms": dict(env="digail/FourRooms-v0", demos="digail/fourrooms/expert-v0", gail=False, compose=False),
    "circleworld": dict(env="digail/CircleWorld-v0", demos="digail/circleworld/expert-v0", gail=True,
                        compose=True),
}


def sh(args: list[str]) -> None:
    print("$ digail " + " ".join(shlex.quote(a) for a in args), flush=True)
    t0 = time.perf_counter()
    subprocess.run([*DIGAIL, *args], check=True, stdout=subprocess.DEVNULL)
    print(f"  ({time.perf_counter() - t0:.0f}s)", flush=True)


def load(path: Path) -> dict[str, Any]:
    return json.loads(path.read_text())


def reversed_schedule(vae: Path) -> str:
    """Counter-clockwise first, then clockwise, in the code ids the VAE's segmentation matched to those labels."""
    schedule = schedule_in_codes(env_spec(TASKS["circleworld"]["env"]).compose_schedule,
                                 load(vae / "segmentation.json")["mapping"])
    if schedule is None:
        raise SystemExit(f"{vae}: the segmentation gave no code of its own to each circle; nothing to compose")
    return schedule


def run_seed(task: dict[str, Any], root: Path, seed: int, episodes: int) -> dict[str, Any]:
    rec: dict[str, Any] = {}
    vae = root / f"vae_s{seed}"
    if not (vae / "model.pt").exists():
        sh(["pretrain", "--demos", task["demos"], "--seed", str(seed), "--out", str(vae), "--force"])
    rec["segmentation"] = load(vae / "segmentation.json")
    rec["vae_time_s"] = load(vae / "config.json").get("train_time_s")
    variants: list[tuple[str, list[str]]] = [("digail", ["--method", "digail", "--vae", str(vae)])]
    if task["gail"]:
        variants += [("digail_l2", ["--method", "digail", "--vae", str(vae), "--bc-weight", "100"]),
                     # plain GAIL trains a fresh policy: the paper's learning rate, not the fine-tuning one, and no
                     # anchor to its random initialisation
                     ("gail", ["--method", "gail", "--train.ppo.policy-lr", "3e-4", "--train.anchor-weight", "0"])]
    runs = {"vae": vae}
    for name, flags in variants:
        run = root / f"{name}_s{seed}"
        runs[name] = run
        if not (run / "model.pt").exists():
            sh(["train", *flags, "--demos", task["demos"], "--seed", str(seed), "--out", str(run), "--force"])
    for name, run in runs.items():
        if not (run / "eval.json").exists() or load(run / "eval.json").get("episodes") != episodes:
            sh(["evaluate", str(run), "--episodes", str(episodes)])
        rec[name] = load(run / "eval.json")
    if task["compose"]:
        schedule = reversed_schedule(vae)
        for name in ("vae", "digail"):
            sh(["compose", str(runs[name]), "--schedule", schedule, "--episodes", "100"])
            rec[f"compose_{name}"] = load(runs[name] / "compose.json")
    return rec


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("task", choices=sorted(TASKS))
    parser.add_argument("--seeds", type=int, nargs="+", default=[0, 1, 2])
    parser.add_argument("--episodes", type=int, default=300)
    parser.add_argument("--root", default="runs/results")
    parser.add_argument("--only-seeds", action="store_true", help="run the seeds, write no table")
    args = parser.parse_args()
    task = TASKS[args.task]
    root = Path(args.root) / args.task
    per_seed = {str(seed): run_seed(task, root, seed, args.episodes) for seed in args.seeds}
    if args.only_seeds:
        return
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
