"""Does each piece of the fast path (`digail.algos.fast`) still pay? Fast against reference, side by side, rounds
interleaved in one process, medians of per-round ratios.

    python benchmarks/studies/fast_path.py [--rounds 5] [--out runs/bench/fast_path.json]

- `step`: `LeanStep` (clipping and fused Adam as direct foreach calls) against `clip_grad_norm_(foreach=True)` and
  `torch.optim.Adam(fused=True).step()`, 3000 steps of random gradients on 2x64 policy and value nets; also
  whether the weights end identical;
- `ppo_update`: 10 epochs on random batches of Circle-World's size (512 rows, minibatch 128) and Hopper's (4096,
  512): the fast path, the fast step with autograd (`hand_grad=False`), and the reference;
- `vae`: ELBO pre-training (`--vae.init none`, batch 16) on the shipped Circle-World (20 epochs) and Four Rooms
  (4 epochs) demonstrations, `FusedVAEStep` against autograd.
"""

from __future__ import annotations

import argparse
import json
import statistics
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import torch

from digail.algos import fast
from digail.algos.batch import PPOBatch
from digail.algos.fast.step import LeanStep
from digail.algos.optim import adam
from digail.algos.ppo import ppo_update
from digail.algos.vae_pretrain import pretrain
from digail.config import PPOConfig, VAEConfig
from digail.data.minari_io import load_dataset
from digail.nets.critic import ValueNet
from digail.nets.policy import ActionSpec, SubtaskPolicy
from digail.utils import set_torch_threads


def _interleaved(fns: dict[str, Callable[[], Any]], rounds: int) -> dict[str, list[float]]:
    times: dict[str, list[float]] = {name: [] for name in fns}
    for r in range(rounds):
        for name in (list(fns) if r % 2 == 0 else list(fns)[::-1]):
            t = time.perf_counter()
            fns[name]()
            times[name].append(time.perf_counter() - t)
    return times


def _summary(times: dict[str, list[float]], base: str) -> dict[str, Any]:
    out: dict[str, Any] = {"median_s": {k: round(statistics.median(v), 4) for k, v in times.items()}}
    for name, v in times.items():
        if name != base:
            ratios = [a / b for a, b in zip(v, times[base], strict=True)]
            out[f"{name}_over_{base}"] = round(statistics.median(ratios), 3)
    return out


def step_study(rounds: int) -> dict[str, Any]:
    def run(kind: str) -> torch.Tensor:
        torch.manual_seed(0)
        nets = [torch.nn.Sequential(torch.nn.Linear(14, 64), torch.nn.Tanh(), torch.nn.Linear(64, 64), torch.nn.Tanh(),
                                    torch.nn.Linear(64, out)) for out in (3, 1)]
        params = [p for n in nets for p in n.parameters()]
        opt = adam(params, 3e-4)
        lean = LeanStep(opt, 0.5)
        for i in range(3000):
            g = torch.Generator().manual_seed(i)
            for p in params:
                p.grad = torch.randn(p.shape, generator=g)
            if kind == "fast":
                lean()
            else:
                torch.nn.utils.clip_grad_norm_(params, 0.5, foreach=True)
                opt.step()
        return torch.cat([p.detach().flatten() for p in params])

    same = torch.equal(run("fast"), run("reference"))
    return {**_summary(_interleaved({"fast": lambda: run("fast"), "reference": lambda: run("reference")}, rounds),
                       "fast"), "identical_weights": same}


def ppo_study(rounds: int) -> dict[str, Any]:
    def update(obs: int, codes: int, act: int, n: int, mb: int, mode: str) -> None:
        torch.manual_seed(0)
        pi, v = SubtaskPolicy(obs, codes, ActionSpec(False, act)), ValueNet(obs, codes)
        g = torch.Generator().manual_seed(1)
        o, c = torch.randn(n, obs, generator=g), torch.eye(codes)[torch.randint(codes, (n,), generator=g)]
        with torch.no_grad():
            d = pi.dist(o, c)
            a = d.sample()
            batch = PPOBatch(o, c, a, d.log_prob(a), torch.randn(n, generator=g), torch.randn(n, generator=g))
        opt = adam([*pi.parameters(), *v.parameters()], 3e-4)
        cfg = PPOConfig(batch_size=n, minibatch_size=mb, epochs=10)
        if mode == "reference":
            with fast.reference():
                ppo_update(pi, v, opt, batch, cfg, torch.Generator().manual_seed(0))
        else:
            ppo_update(pi, v, opt, batch, cfg, torch.Generator().manual_seed(0), hand_grad=mode == "fast")

    out = {}
    for name, size in {"circle-world (512 rows, minibatch 128)": (2, 2, 2, 512, 128),
                       "hopper (4096 rows, minibatch 512)": (11, 4, 3, 4096, 512)}.items():
        update(*size, "fast")  # TorchScript compiles once
        fns = {mode: (lambda mode=mode, size=size: update(*size, mode))
               for mode in ("fast", "step_with_autograd", "reference")}
        out[name] = _summary(_interleaved(fns, rounds), "fast")
    return out


def vae_study(rounds: int) -> dict[str, Any]:
    out = {}
    for dataset, codes, epochs in (("digail/circleworld/expert-v0", 2, 20), ("digail/fourrooms/expert-v0", 4, 4)):
        trajs = load_dataset(dataset).trajs
        cfg = VAEConfig(codes=codes, epochs=epochs, batch_size=16, init="none", tau_decay=3e-3)
        pretrain(trajs, cfg, seed=0, progress=False)  # TorchScript compiles once

        def reference(trajs: Any = trajs, cfg: VAEConfig = cfg) -> None:
            with fast.reference():
                pretrain(trajs, cfg, seed=0, progress=False)

        fns = {"fast": lambda trajs=trajs, cfg=cfg: pretrain(trajs, cfg, seed=0, progress=False),
               "reference": reference}
        out[f"{dataset} ({epochs} epochs)"] = _summary(_interleaved(fns, rounds), "fast")
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--rounds", type=int, default=5)
    parser.add_argument("--only", nargs="*", default=["step", "ppo_update", "vae"])
    parser.add_argument("--out", default="runs/bench/fast_path.json")
    args = parser.parse_args()
    set_torch_threads(1)
    studies = {"step": step_study, "ppo_update": ppo_study, "vae": vae_study}
    results = {name: studies[name](args.rounds) for name in args.only}
    Path(args.out).parent.mkdir(parents=True, exist_ok=True)
    Path(args.out).write_text(json.dumps(results, indent=2) + "\n")
    print(json.dumps(results, indent=2))


if __name__ == "__main__":
    main()
