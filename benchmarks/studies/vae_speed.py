"""VAE pre-training and polish speed of this checkout against another commit's code, side by side in one run.

    python benchmarks/studies/vae_speed.py --baseline REV [--dataset digail/circleworld/expert-v0]
        [--preset circle-world] [--epochs N] [--polish-steps N] [--rounds 3]

Each round runs the baseline's `src` (extracted with `git archive`) and this checkout's in fresh subprocesses,
one after the other, so that a shared machine's drifting load hits both alike: `pretrain` with each side's own
version of the preset (its hard-EM start where it has one; `--epochs` overrides the epochs), then `polish` for
`--polish-steps` (default: the preset's; 0: none), one torch thread. Round r uses seed `--seed` + r, so that three
rounds score three seeds. Writes runs/bench/vae_speed.json (`--out`; the published measurements are
benchmarks/results/speed/vae_speed.json): each side's epochs, start and seconds of pre-training
and polish (medians over rounds), the new-over-old speed-ups (medians of per-round ratios, wall clock and the
process's CPU time), a hash of each side's final weights (equal hashes: the same numbers bit for bit) and, where
the demonstrations carry oracle labels, each side's segmentation scores per seed (causal decoding after the
polish: accuracy, NMI, boundary F1).
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[2]

CHILD = r"""
import hashlib, json, sys, time
from dataclasses import replace
import torch
torch.set_num_threads(1)
import torch._dynamo  # imported by the first Adam: kept out of the timings
from digail.algos.polish import polish
from digail.algos.vae_pretrain import pretrain
from digail.preset import get_preset
from digail.data.minari_io import load_dataset
dataset, preset, epochs, steps, seed = sys.argv[1], sys.argv[2], int(sys.argv[3]), int(sys.argv[4]), int(sys.argv[5])
trajs = list(load_dataset(dataset).trajs)
base = get_preset(preset).vae
cfg = replace(base, epochs=base.epochs if epochs < 0 else epochs,
              polish_steps=base.polish_steps if steps < 0 else steps)
t0, c0 = time.perf_counter(), time.process_time()
model, history = pretrain(trajs, replace(cfg, polish_steps=0), seed=seed, progress=False)
t1, c1 = time.perf_counter(), time.process_time()
if cfg.polish_steps:
    polish(model, trajs, cfg, seed=seed, progress=False)
t2, c2 = time.perf_counter(), time.process_time()
sd = model.state_dict()
digest = hashlib.sha256(b"".join(sd[k].detach().numpy().tobytes() for k in sorted(sd))).hexdigest()[:16]
out = {"seed": seed, "epochs": len(history["epoch"]), "init": getattr(cfg, "init", "none"),
       "init_steps": getattr(cfg, "init_steps", 0), "polish_steps": cfg.polish_steps, "pretrain_s": t1 - t0,
       "polish_s": t2 - t1, "pretrain_cpu_s": c1 - c0, "polish_cpu_s": c2 - c1,
       "demo_steps": sum(len(t) for t in trajs), "hash": digest}
if all(t.subtasks is not None for t in trajs):
    from digail.algos.decode import segment_many
    from digail.eval.segmentation import segmentation_metrics
    scores = segmentation_metrics(segment_many(model.eval(), trajs), [t.subtasks for t in trajs])
    out.update({k: float(scores[k]) for k in ("accuracy", "nmi", "boundary_f1")})
print(json.dumps(out))
"""


def run_side(src: Path, args: argparse.Namespace, seed: int) -> dict[str, float | str]:
    env = {**os.environ, "PYTHONPATH": str(src), "OMP_NUM_THREADS": "1", "MUJOCO_GL": "egl"}
    out = subprocess.run([sys.executable, "-c", CHILD, args.dataset, args.preset, str(args.epochs),
                          str(args.polish_steps), str(seed)], env=env, check=True, capture_output=True, text=True)
    return json.loads(out.stdout.strip().splitlines()[-1])  # type: ignore[no-any-return]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--baseline", required=True, help="git revision to compare against (e.g. main)")
    parser.add_argument("--dataset", default="digail/circleworld/expert-v0")
    parser.add_argument("--preset", default="circle-world")
    parser.add_argument("--epochs", type=int, default=-1, help="VAE epochs (-1: the preset's)")
    parser.add_argument("--polish-steps", type=int, default=-1, help="polish steps (-1: the preset's)")
    parser.add_argument("--rounds", type=int, default=3)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--out", default="runs/bench/vae_speed.json")
    args = parser.parse_args()

    with tempfile.TemporaryDirectory() as tmp:
        archive = subprocess.run(["git", "-C", str(ROOT), "archive", args.baseline, "src"], check=True,
                                 capture_output=True).stdout
        subprocess.run(["tar", "-x", "-C", tmp], input=archive, check=True)
        sides = {"old": Path(tmp) / "src", "new": ROOT / "src"}
        samples: dict[str, list[dict[str, float | str]]] = {k: [] for k in sides}
        for r in range(args.rounds):
            for name, src in sides.items():
                samples[name].append(run_side(src, args, args.seed + r))
            print(f"round {r + 1}: " + ", ".join(f"{k} pretrain {v[-1]['pretrain_s']:.1f}s polish "
                                                 f"{v[-1]['polish_s']:.1f}s" for k, v in samples.items()), flush=True)

    def col(name: str, key: str) -> np.ndarray:
        return np.array([float(s[key]) for s in samples[name]])

    steps = int(samples["new"][0]["polish_steps"])
    # each side runs its own version of the preset: the epochs, hard-EM start and polish it actually did
    results: dict[str, object] = {"baseline": args.baseline, "dataset": args.dataset, "preset": args.preset,
                                  **{f"{k}_{key}": samples[k][0].get(key) for k in sides
                                     for key in ("epochs", "init", "init_steps", "polish_steps")},
                                  "rounds": args.rounds,
                                  "seeds": [args.seed + r for r in range(args.rounds)],
                                  "cpus": len(os.sched_getaffinity(0)), "loadavg": list(os.getloadavg())}
    for name in sides:
        results[f"{name}_pretrain_s"] = float(np.median(col(name, "pretrain_s")))
        results[f"{name}_polish_s"] = float(np.median(col(name, "polish_s")))
        if int(samples[name][0]["epochs"]):
            results[f"{name}_s_per_epoch"] = results[f"{name}_pretrain_s"] / int(samples[name][0]["epochs"])
        if steps:
            results[f"{name}_ms_per_polish_step"] = 1e3 * float(np.median(col(name, "polish_s"))) / steps
        results[f"{name}_hash"] = [str(s["hash"]) for s in samples[name]]
    for clock in ("", "_cpu"):
        results[f"speedup_pretrain{clock}"] = float(np.median(col("old", f"pretrain{clock}_s")
                                                              / col("new", f"pretrain{clock}_s")))
        if steps:
            results[f"speedup_polish{clock}"] = float(np.median(col("old", f"polish{clock}_s")
                                                                / col("new", f"polish{clock}_s")))
        both = {k: col(k, f"pretrain{clock}_s") + col(k, f"polish{clock}_s") for k in sides}
        results[f"speedup_total{clock}"] = float(np.median(both["old"] / both["new"]))
    results["same_weights"] = results["old_hash"] == results["new_hash"]
    if "accuracy" in samples["new"][0]:
        for key in ("accuracy", "nmi", "boundary_f1"):
            results[f"seg_{key}"] = {k: col(k, key).round(4).tolist() for k in sides}
    results["samples"] = samples
    Path(args.out).parent.mkdir(parents=True, exist_ok=True)
    Path(args.out).write_text(json.dumps(results, indent=2) + "\n")
    print(json.dumps({k: v for k, v in results.items() if k != "samples"}, indent=2))


if __name__ == "__main__":
    main()
