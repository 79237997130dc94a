"""SAC on few-demonstration Fetch: what an env step costs, today's schedule against cheaper ones, in one run.

    python benchmarks/studies/sac_fetch_speed.py --vae runs/fetchfew/d4/bc_k4_s0 [--steps 400] [--rounds 2]

The learner of `benchmarks/fetch_fewdemo.sh 4 digail-l2-rel-sac 0`: Directed-Info GAIL + L2 (BC weight 1.0) from
the VAE, D on Fetch's relative view with the gradient penalty, one env, one torch thread. Each variant is built
once, warmed up past the learning start, then timed on `--steps` env steps per round, the variants in turn each
round (so drifting load on a shared machine hits them alike); medians over the rounds. Timed by this process's
CPU time (steps per CPU second) and by the wall clock. Variants:

- today: one update of batch 256 per env step (utd 1), D stepped every env step;
- every4_b1024: one update every 4 env steps on a batch 4x as large (`--train.sac.utd 0.25
  --train.sac.batch-size 1024`), D as today: the same transitions seen per env step, fewer, larger products;
- every2_b256, every4_b256: one update of batch 256 every 2 (4) env steps (`--train.sac.utd 0.5`, `0.25`);
- every4_b256_d4: that, with D stepped every 4 env steps on a minibatch 4x as large (`--train.imitation.disc-every 4
  --train.imitation.disc-minibatch-size 1024`: the same D samples per env step);
- today_nobc, every4_b256_nobc: without the BC term (the hand-written gradients then run: what BC costs).

`cpu_minutes_1m_*` projects the CPU minutes of 1M env steps from the CPU rate. The result goes to `--out`.
"""

from __future__ import annotations

import argparse
import json
import os
import time
from dataclasses import replace
from pathlib import Path
from typing import Any

import numpy as np

os.environ.setdefault("MUJOCO_GL", "egl")

VARIANTS: dict[str, dict[str, Any]] = {
    "today": {},
    "every4_b1024": {"sac": {"utd": 0.25, "batch_size": 1024}},
    "every2_b256": {"sac": {"utd": 0.5}},
    "every4_b256": {"sac": {"utd": 0.25}},
    "every4_b256_d4": {"sac": {"utd": 0.25, "disc_every": 4}, "disc_minibatch_size": 1024},
    "today_nobc": {"bc_weight": 0.0},
    "every4_b256_nobc": {"sac": {"utd": 0.25}, "bc_weight": 0.0},
}


def runner(vae: Path, change: dict[str, Any], warmup: int) -> Any:
    """A function timing `steps` env steps (each with its share of updates) of one variant, after its warm-up."""
    from digail.algos.directed_info_gail import build_trainer
    from digail.checkpoint import load_model
    from digail.commands.train import load_demos
    from digail.config import SACConfig
    from digail.preset import get_preset

    demos, env_id = load_demos("digail/fetchpickandplace/expert-v0", episodes=4)
    model, _ = load_model(vae / "model.pt")
    base = get_preset("fetch").train
    sac = replace(SACConfig(), steps_per_iteration=warmup, learning_starts=warmup // 2, policy_warmup=0,
                  buffer_size=100_000, **change.get("sac", {}))
    cfg = replace(base, learner="sac", sac=sac, bc_weight=change.get("bc_weight", 1.0), disc_obs="relative",
                  replay_fraction=0.0, closed_loop_codes="argmax", backend="sync",
                  disc_minibatch_size=change.get("disc_minibatch_size", base.disc_minibatch_size))
    trainer = build_trainer(env_id, demos, cfg, vae_model=model, seed=0, run_dir=None, progress=False)
    loop = trainer.learner
    trainer.iterate()

    def run(steps: int) -> tuple[float, float]:
        w0, c0 = time.perf_counter(), time.process_time()
        with trainer.frozen_codes():
            for _ in range(steps):
                loop.step_and_update()
        return steps / (time.perf_counter() - w0), steps / max(time.process_time() - c0, 1e-9)

    return run


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--vae", type=Path, required=True, help="a K = 4 Fetch VAE run (fetch_fewdemo.sh 4 bc 0)")
    parser.add_argument("--steps", type=int, default=400)
    parser.add_argument("--rounds", type=int, default=2)
    parser.add_argument("--warmup", type=int, default=600)
    parser.add_argument("--only", nargs="*", default=list(VARIANTS), choices=list(VARIANTS))
    parser.add_argument("--out", default="benchmarks/studies/results/sac_fetch_speed.json")
    args = parser.parse_args()
    import torch

    from digail.utils import keep_heap_pages, set_torch_threads

    set_torch_threads(1)
    keep_heap_pages()
    runs = {name: runner(args.vae, VARIANTS[name], args.warmup) for name in args.only}
    samples: dict[str, list[tuple[float, float]]] = {k: [] for k in runs}
    for r in range(args.rounds):
        for name, run in runs.items():
            samples[name].append(run(args.steps))
            print(f"round {r}: {name} {samples[name][-1][0]:.1f} steps/s, {samples[name][-1][1]:.1f} steps per "
                  "CPU second", flush=True)
    result: dict[str, Any] = {"env": "digail/FetchPickAndPlace-v4", "vae": str(args.vae), "steps": args.steps,
                              "rounds": args.rounds, "torch": torch.__version__, "torch_threads": 1,
                              "loadavg_start": os.getloadavg()[0], "variants": VARIANTS}
    for name, vals in samples.items():
        cpu = float(np.median([c for _, c in vals]))
        result[f"sps_{name}"] = float(np.median([w for w, _ in vals]))
        result[f"cpu_sps_{name}"] = cpu
        result[f"cpu_sps_{name}_samples"] = [round(c, 2) for _, c in vals]
        result[f"cpu_minutes_1m_{name}"] = 1e6 / cpu / 60
    if "today" in samples:
        for name in samples:
            result[f"cpu_ratio_{name}"] = result[f"cpu_sps_{name}"] / result["cpu_sps_today"]
    result["loadavg_end"] = os.getloadavg()[0]
    Path(args.out).parent.mkdir(parents=True, exist_ok=True)
    Path(args.out).write_text(json.dumps(result, indent=2) + "\n")
    print(json.dumps({k: round(v, 2) for k, v in result.items() if isinstance(v, float)}, indent=1))
    print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
