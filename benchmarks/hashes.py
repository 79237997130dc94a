"""Behaviour fingerprint: sha256 of the weights and metrics of short fixed-seed runs on Circle-World, Four Rooms
and Hopper (pre-training with each env's preset, then a few Directed-Info GAIL iterations with PPO, and with SAC on
Circle-World and Hopper: the reference update with a BC term and the hand-written one with absorbing states).

A refactor that must not change behaviour prints the same lines before and after:

    python benchmarks/hashes.py --out runs/hashes

Timing columns (`perf/*`, `time/s`) are left out of the metrics' hash; everything else in `losses.csv`,
`metrics.csv` and every tensor in `model.pt` counts, bit for bit.
"""

from __future__ import annotations

import argparse
import csv
import hashlib
import shutil
import subprocess
import sys
from pathlib import Path
from typing import Any

import torch

RUNS: dict[str, tuple[str, list[str], list[str]]] = {
    # name: (dataset, pretrain flags, train flags)
    "circle-world": ("digail/circleworld/expert-v0",
                     ["--vae.init-steps", "300", "--vae.polish-steps", "200"],
                     ["--train.iterations", "3", "--train.value-warmup", "1"]),
    "four-rooms": ("digail/fourrooms/expert-v0",
                   ["--vae.epochs", "3", "--vae.polish-steps", "200"],
                   ["--train.iterations", "3", "--train.value-warmup", "1"]),
    "hopper": ("digail/hopper/expert-v0",
               ["--vae.init-steps", "200"],
               ["--train.iterations", "2", "--train.value-warmup", "1", "--train.ppo.batch-size", "512",
                "--train.ppo.minibatch-size", "128", "--train.ppo.no-compile", "--train.backend", "sync"]),
    "circle-world-sac": ("digail/circleworld/expert-v0",
                         ["--vae.init-steps", "300", "--vae.polish-steps", "200"],
                         ["--train.learner", "sac", "--train.iterations", "2", "--train.sac.steps-per-iteration",
                          "200", "--train.sac.learning-starts", "100", "--train.sac.batch-size", "64",
                          "--train.sac.policy-warmup", "50", "--train.sac.hidden", "64", "64",
                          "--train.anchor-weight", "0", "--train.bc-weight", "0.1"]),
    "hopper-sac": ("digail/hopper/expert-v0",
                   ["--vae.init-steps", "200"],
                   ["--train.learner", "sac", "--train.iterations", "2", "--train.sac.steps-per-iteration", "200",
                    "--train.sac.learning-starts", "100", "--train.sac.batch-size", "64", "--train.sac.policy-warmup",
                    "50", "--train.sac.hidden", "64", "64", "--train.sac.absorbing", "--train.backend", "sync"]),
}


def _tensors(obj: Any, prefix: str = "") -> list[tuple[str, torch.Tensor]]:
    """Every tensor inside a (nested) checkpoint object, with its key path, in a fixed order."""
    if isinstance(obj, torch.Tensor):
        return [(prefix, obj)]
    if isinstance(obj, dict):
        return [t for k in sorted(obj, key=str) for t in _tensors(obj[k], f"{prefix}/{k}")]
    if isinstance(obj, list | tuple):
        return [t for i, v in enumerate(obj) for t in _tensors(v, f"{prefix}/{i}")]
    return []


def weights_hash(path: Path) -> str:
    h = hashlib.sha256()
    for key, t in _tensors(torch.load(path, map_location="cpu", weights_only=False)):
        h.update(key.encode())
        h.update(t.detach().contiguous().cpu().numpy().tobytes())
    return h.hexdigest()


def metrics_hash(path: Path) -> str:
    h = hashlib.sha256()
    with open(path, newline="") as f:
        rows = list(csv.reader(f))
    keep = [i for i, name in enumerate(rows[0]) if not (name.startswith("perf/") or name.startswith("time/"))]
    for row in rows:
        h.update(",".join(row[i] for i in keep if i < len(row)).encode() + b"\n")
    return h.hexdigest()


def _digail(args: list[str]) -> None:
    proc = subprocess.run([sys.executable, "-m", "digail.cli", *args], capture_output=True, text=True)
    if proc.returncode != 0:
        raise SystemExit(f"digail {' '.join(args)} failed:\n{proc.stderr[-2000:]}")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", type=Path, default=Path("runs/hashes"))
    parser.add_argument("--only", nargs="*", default=list(RUNS), choices=list(RUNS))
    args = parser.parse_args()
    shutil.rmtree(args.out, ignore_errors=True)
    args.out.mkdir(parents=True)
    for name in args.only:
        demos, pre, train = RUNS[name]
        vae, run = args.out / f"{name}_vae", args.out / f"{name}_train"
        _digail(["pretrain", "--demos", demos, "--seed", "0", "--out", str(vae), *pre])
        _digail(["train", "--demos", demos, "--vae", str(vae), "--seed", "0", "--out", str(run), *train])
        for what, digest in (("vae weights", weights_hash(vae / "model.pt")),
                             ("vae losses", metrics_hash(vae / "losses.csv")),
                             ("train weights", weights_hash(run / "model.pt")),
                             ("train metrics", metrics_hash(run / "metrics.csv"))):
            print(f"{name:13s} {what:14s} {digest}", flush=True)


if __name__ == "__main__":
    main()
