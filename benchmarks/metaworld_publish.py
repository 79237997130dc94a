"""Publish the Meta-World few-demonstration runs: the median seed's run folders and a video per task.

    MUJOCO_GL=egl python benchmarks/metaworld_publish.py --runs runs/mwfew [--tasks box-close ...]

For every task and adversarial method in `results/metaworld/metaworld_fewdemo.json`, at the longest training with three
seeds (the run folders hold their last training only), the seed
whose success is the median of the three (the lower seed on a tie) is copied (model, config, evaluation, metrics;
no checkpoint) to `results/runs/metaworld_<task>_<method>_s<seed>`, where tests/test_committed_runs.py evaluates
it again. Each such task gets a video of its Directed-Info GAIL run (`digail video`, the first evaluation episode,
the active code on every frame) in `results/videos/metaworld/`; a task with BC rows only gets its seed-0 VAE's.
"""

from __future__ import annotations

import argparse
import json
import shutil
from pathlib import Path

from digail.sweep.publish import make_portable

HERE = Path(__file__).resolve().parent
RESULTS = HERE / "results"
KEEP = ("model.pt", "config.json", "eval.json", "metrics.csv")


def median_seed(rows: list[dict]) -> int:
    ranked = sorted(rows, key=lambda r: (r["success_rate"], r["seed"]))
    return ranked[(len(ranked) - 1) // 2]["seed"]


def video(run: Path, name: str) -> None:
    from digail.cli import main as digail

    if digail(["video", str(run), "--name", name]) != 0:
        raise SystemExit(f"digail video {run} failed")
    dest = RESULTS / "videos" / "metaworld"
    dest.mkdir(parents=True, exist_ok=True)
    shutil.copyfile(run / "videos" / f"{name}.mp4", dest / f"{name}.mp4")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--runs", type=Path, default=Path("runs/metaworld_fewdemo"))
    parser.add_argument("--tasks", nargs="+", help="only these tasks (default: every task in the JSON)")
    parser.add_argument("--methods", nargs="+", default=["digail-l2", "flatbc-l2"])
    args = parser.parse_args()
    rows = json.loads((RESULTS / "metaworld" / "metaworld_fewdemo.json").read_text())["rows"]
    tasks = args.tasks or list(dict.fromkeys(r["task"] for r in rows))
    for task in tasks:
        trained = False
        for method in args.methods:
            mine = [r for r in rows if r["task"] == task and r["method"] == method and r.get("iterations")]
            budgets = [n for n in {r["iterations"] for r in mine} if sum(r["iterations"] == n for r in mine) >= 3]
            if not budgets:
                continue
            got = [r for r in mine if r["iterations"] == max(budgets)]
            trained = True
            seed = median_seed(got)
            source = args.runs / task / f"{method}_s{seed}"
            dest = RESULTS / "runs" / f"metaworld_{task}_{method}_s{seed}"
            dest.mkdir(parents=True, exist_ok=True)
            for name in KEEP:
                shutil.copyfile(source / name, dest / name)
            make_portable(dest)
            print(f"{task} {method}: seed {seed} -> {dest.relative_to(HERE.parent)}")
            if method == "digail-l2":
                video(source, f"{task}_{method}_s{seed}_seed10000")
        if not trained and (args.runs / task / "bc_s0" / "model.pt").is_file():
            video(args.runs / task / "bc_s0", f"{task}_bc_s0_seed10000")


if __name__ == "__main__":
    main()
