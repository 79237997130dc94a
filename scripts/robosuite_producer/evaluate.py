"""Roll a digail policy out in robosuite and count successes: the VAE's hierarchical policy (closed-loop
c_t = argmax q(. | s_t, c_{t-1}), then the mode of pi(a | s_t, c_t)), or flat behaviour cloning (a K = 1 VAE).

Runs in the producer's environment with torch (CPU) and digail added without its dependencies:

    rsvenv/bin/pip install /path/to/torch-2.13.0+cpu-....whl   # or torch==2.13.0 from a CPU index, first
    rsvenv/bin/pip install --no-deps -e .
    rsvenv/bin/pip install gymnasium tyro "numpy<2"
    rsvenv/bin/python scripts/robosuite_producer/evaluate.py RUN --task Stack --episodes 50 --seed 1000 --json OUT

The checkpoint is loaded with `digail.checkpoint.load_model` (`torch.load(..., weights_only=True)`). The
observation is built as digail read the demonstrations: robomimic's low-dimensional keys (`produce.robomimic_obs`)
flattened in sorted name order, as float32. The environment is made with the producer's kwargs and
`robosuite.make(seed=SEED)`, so the placements differ from the demonstrations' (seed 0) but repeat from run to run.
An episode succeeds when `env._check_success()` is true at any step within `--horizon` steps.
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import numpy as np
import torch
from produce import make_env, robomimic_obs

from digail.checkpoint import load_model


def flatten(raw: dict) -> np.ndarray:
    obs = robomimic_obs(raw)
    return np.concatenate([np.asarray(obs[k], np.float32).reshape(-1) for k in sorted(obs)])


@torch.no_grad()
def run(run_dir: Path, task: str, episodes: int, seed: int, horizon: int) -> dict:
    torch.set_num_threads(1)
    model, meta = load_model(run_dir)
    model.eval()
    env, _ = make_env(task, seed)
    eye = torch.eye(model.codes)
    successes, lengths, switches, t0, steps = [], [], [], time.time(), 0
    for _ in range(episodes):
        raw = env.reset()
        prev = torch.zeros(1, model.codes)  # c_{-1}: the start input
        codes, ok = [], False
        for _ in range(horizon):
            obs = torch.as_tensor(flatten(raw))[None]
            if obs.shape[1] != model.obs_dim:
                raise SystemExit(f"{run_dir} takes {model.obs_dim} observation numbers, the env gives {obs.shape[1]}")
            obs_n = model.normalizer(obs)
            c = int(model.q(obs_n, prev).argmax(-1)) if model.codes > 1 else 0
            codes.append(c)
            prev = eye[c][None]
            action = model.pi.mode(obs_n, eye[c][None])[0].numpy().astype(np.float64)
            raw, _, _, _ = env.step(np.clip(action, -1, 1))
            steps += 1
            if env._check_success():
                ok = True
                break
        successes.append(ok)
        lengths.append(len(codes))
        switches.append(int(np.count_nonzero(np.diff(codes))))
    seconds = time.time() - t0
    return {"run": str(run_dir), "codes": model.codes, "task": task, "episodes": episodes, "seed": seed,
            "horizon": horizon, "success_rate": float(np.mean(successes)), "successes": int(np.sum(successes)),
            "mean_length": float(np.mean(lengths)), "switches_per_episode": float(np.mean(switches)),
            "seconds": round(seconds, 1), "env_steps_per_second": round(steps / seconds, 1),
            "deterministic": True, "macro_policy": "closed-loop argmax q" if model.codes > 1 else "none (K = 1)"}


def main() -> None:
    parser = argparse.ArgumentParser(description=(__doc__ or "").splitlines()[0])
    parser.add_argument("run", type=Path)
    parser.add_argument("--task", choices=["Stack", "PickPlaceCan"], required=True)
    parser.add_argument("--episodes", type=int, default=50)
    parser.add_argument("--seed", type=int, default=1000)
    parser.add_argument("--horizon", type=int, default=300)
    parser.add_argument("--json", type=Path)
    args = parser.parse_args()
    result = run(args.run, args.task, args.episodes, args.seed, args.horizon)
    print(json.dumps(result))
    if args.json is not None:
        args.json.parent.mkdir(parents=True, exist_ok=True)
        args.json.write_text(json.dumps(result, indent=1) + "\n")


if __name__ == "__main__":
    main()
