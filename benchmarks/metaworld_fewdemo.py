"""Few-demonstration imitation on Meta-World, a one-seed screen: behaviour cloning with and without codes.

    python benchmarks/metaworld_fewdemo.py                   # -> results/metaworld/metaworld_fewdemo.json
    python benchmarks/metaworld_fewdemo.py --tasks pick-place --methods bc flatbc --seeds 0 --out runs/few.json

Per (task, method, seed), from the first `--demos` episodes of the task's shipped demonstrations (seeds 0..N-1):

    bc      the VAE's policy (K = the expert's phase count, `digail.envs.metaworld.phase_counts`), closed-loop q:
            digail pretrain --demos D --demos-episodes N --codes K --seed S --out R/TASK/bc_sS
    flatbc  the same pre-training with one code, a flat behaviour-cloned policy of the same network:
            digail pretrain --demos D --demos-episodes N --codes 1 --seed S --out R/TASK/flatbc_sS
    digail-l2, flatbc-l2  (with --iterations N) Directed-Info GAIL + L2 from bc's VAE, GAIL + L2 from flatbc's
            policy (one code: no bonus), the task's preset (PPO, batch 4096 over 8 envs, the step-cost reward):
            digail train --demos D --demos-episodes N --vae R/TASK/bc_sS --train.bc-weight 1.0 --train.iterations I ...
            (a run of fewer iterations is continued: digail train --resume RUN --until I). The first 10 iterations
            train the value function only (`--train.value-warmup`): the policy moves from iteration 11 on.
    digail-l2-noise, flatbc-l2-noise  the same with D's inputs noised (`--train.imitation.disc-noise 0.15`), the
            few-demonstration Fetch screen's highest reward at 205k env steps (docs/howto/few-demos-reward.md)

then `digail evaluate RUN --episodes E` on fresh placements (the evaluation seeds, 10000 on); the row keeps the
success rate, the mean episode length and the commands. A bc row also keeps how well its codes segment the task's
50 shipped demonstrations (`digail segment RUN`, the offline reading, against the expert's phases): what a change of
the segmentation start (`--pretrain-args`, e.g. `--vae.init-actions gaussian --vae.init-ridge 1.0` for the start
before 2026-12-07) does to the codes can be set beside what it does to success. Both pre-trainings use the task's
preset (metaworld: the default VAE).
"""

from __future__ import annotations

import argparse
import csv
import json
import shlex
import sys
import time
from pathlib import Path
from typing import Any

HERE = Path(__file__).resolve().parent
TASKS = ("pick-place", "hammer", "assembly", "shelf-place")


def run(cmd: list[str]) -> None:
    from digail.cli import main as digail

    print("$ digail " + shlex.join(cmd), flush=True)
    if digail(cmd) != 0:
        raise SystemExit(f"failed: digail {shlex.join(cmd)}")


def one(task: str, method: str, seed: int, args: argparse.Namespace) -> dict[str, Any]:
    from digail.envs.metaworld import phase_counts

    demos = f"digail/metaworld-{task}/expert-v0"
    root = args.runs / task
    common = ["--demos", demos, "--demos-episodes", str(args.demos), "--seed", str(seed)]
    commands: list[list[str]] = []
    folder = root / f"{method}_s{seed}"
    if method in ("bc", "flatbc"):
        codes = phase_counts()[f"{task}-v3"] if method == "bc" else 1
        commands.append(["pretrain", *common, "--codes", str(codes), "--out", str(folder), "--force",
                         *shlex.split(args.pretrain_args)])
        if method == "bc":
            commands.append(["segment", str(folder)])
    else:
        start = root / f"{'bc' if method.startswith('digail-l2') else 'flatbc'}_s{seed}"
        if not (start / "model.pt").is_file():
            raise SystemExit(f"{method} starts from {start}; run {start.name.split('_')[0]} first")
        done = json.loads((folder / "config.json").read_text())["train"]["iterations"] \
            if (folder / "config.json").is_file() else 0
        if 0 < done < args.iterations:  # a shorter run is trained on (the same numbers as one started with more)
            commands.append(["train", "--resume", str(folder), "--until", str(args.iterations)])
        elif done == args.iterations and (folder / "eval.json").is_file():
            return row(task, method, seed, folder, args, ["(done earlier)"], 0.0)
        elif done == args.iterations:  # killed: on from its last checkpoint
            commands.append(["train", "--resume", str(folder)])
        else:
            extra = ["--train.imitation.disc-noise", "0.15"] if method.endswith("-noise") else []
            commands.append(["train", *common, "--vae", str(start), "--train.bc-weight", "1.0", "--train.iterations",
                             str(args.iterations), "--train.checkpoint-every", "5", *extra, "--out", str(folder),
                             "--force"])
    commands.append(["evaluate", str(folder), "--episodes", str(args.episodes)])
    t0 = time.perf_counter()
    for cmd in commands:
        run(cmd)
    return row(task, method, seed, folder, args, ["digail " + shlex.join(c) for c in commands],
               time.perf_counter() - t0)


def row(task: str, method: str, seed: int, folder: Path, args: argparse.Namespace, commands: list[str],
        seconds: float) -> dict[str, Any]:
    ev = json.loads((folder / "eval.json").read_text())
    trained = method not in ("bc", "flatbc")
    segmentation = {}
    if (folder / "segmentation.json").is_file() and method == "bc":
        seg = json.loads((folder / "segmentation.json").read_text())
        kept = {k: seg.get(k) for k in ("accuracy", "boundary_f1_5", "reading", "episodes")}
        causal = (seg.get("readings") or {}).get("causal", {}).get("accuracy")
        segmentation = {"segmentation": {**kept, "causal_accuracy": causal}}
    return {"task": task, "method": method, "seed": seed, "demos": args.demos, "episodes": ev["episodes"],
            "iterations": args.iterations if trained else None,
            "env_steps": args.iterations * 4096 if trained else None,
            "success_rate": ev.get("success_rate"), "mean_length": ev.get("mean_length"),
            "expert_success_rate": (ev.get("expert") or {}).get("success_rate"),
            "minutes": round(seconds / 60, 1), "commands": commands,
            **segmentation, **({"per_iteration": per_iteration(folder / "metrics.csv")} if trained else {})}


def per_iteration(metrics: Path) -> dict[str, list[float | None]]:
    """D's accuracy on expert steps and the imitation reward per agent step, each training iteration: whether
    the reward still teaches (a D that always wins leaves a reward that no longer ranks the agent's steps)."""
    with metrics.open() as f:
        records = list(csv.DictReader(f))
    columns = {"disc_acc_expert": "disc/acc_expert", "disc_reward": "rollout/disc_reward", "sps": "perf/sps"}
    return {name: [round(float(r[c]), 4) if r.get(c) not in (None, "") else None for r in records]
            for name, c in columns.items()}


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--tasks", nargs="+", default=list(TASKS))
    parser.add_argument("--methods", nargs="+", default=["bc", "flatbc"],
                        choices=["bc", "flatbc", "digail-l2", "flatbc-l2", "digail-l2-noise", "flatbc-l2-noise"])
    parser.add_argument("--seeds", nargs="+", type=int, default=[0])
    parser.add_argument("--demos", type=int, default=10)
    parser.add_argument("--episodes", type=int, default=100)
    parser.add_argument("--iterations", type=int, default=10, help="training iterations of the -l2 methods")
    parser.add_argument("--runs", type=Path, default=Path("runs/metaworld_fewdemo"))
    parser.add_argument("--pretrain-args", default="", metavar="FLAGS",
                        help="more `digail pretrain` flags for bc and flatbc, one string (e.g. the segmentation start)")
    parser.add_argument("--out", type=Path, default=HERE / "results" / "metaworld" / "metaworld_fewdemo.json")
    parser.add_argument("--merge", type=Path, nargs="+", metavar="JSON",
                        help="run nothing: add the rows of these files (calls that ran side by side) to --out")
    args = parser.parse_args(argv)
    result: dict[str, Any] = {"rows": []}
    if args.out.exists():  # rows of earlier calls that this one does not rerun are kept
        result = json.loads(args.out.read_text())
    if args.merge:
        for path in args.merge:
            for new in json.loads(path.read_text())["rows"]:
                key = (new["task"], new["method"], new["seed"], new.get("iterations"))
                result["rows"] = [r for r in result["rows"]
                                  if (r["task"], r["method"], r["seed"], r.get("iterations")) != key] + [new]
        args.out.write_text(json.dumps(result, indent=1) + "\n")
        return
    command = "python benchmarks/metaworld_fewdemo.py " + shlex.join(sys.argv[1:] if argv is None else argv)
    for task in args.tasks:
        for method in args.methods:
            for seed in args.seeds:
                row = {**one(task, method, seed, args), "benchmark_command": command}
                key = (task, method, seed, row["iterations"])
                result["rows"] = [r for r in result["rows"] if (r["task"], r["method"], r["seed"],
                                                                r.get("iterations")) != key] + [row]
                print(f"== {task} {method} seed {seed}: success {row['success_rate']:.2f} "
                      f"length {row['mean_length']:.0f} ({row['minutes']} min)", flush=True)
                args.out.parent.mkdir(parents=True, exist_ok=True)
                args.out.write_text(json.dumps(result, indent=1) + "\n")


if __name__ == "__main__":
    main()
