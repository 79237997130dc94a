"""Does overlapping the policy's inference with the workers' stepping pay on this machine? Measured, not assumed.

    python benchmarks/studies/overlap.py [--env Hopper-v5] [--num-envs 8] [--steps 256] [--rounds 5]

Two rollout loops on the subprocess backend, the same total envs and the rollout's per-step inference (q, then pi
and V on NumPy snapshots, `digail.algos.fast.inference`, of an untrained 4-code model; speed does not depend on
the weights):
- `lockstep`: one `SubprocVecEnv` of N envs (one worker per core); each step the main process infers for all N,
  then waits for all N to step (the trainer's loop);
- `halves`: two `SubprocVecEnv`s of N/2 envs (half the workers each); while one half steps, the main process infers
  the other half's next actions, so inference hides behind stepping where a core is free for it.
Writes runs/bench/overlap.json (`--out`; the published measurement is benchmarks/studies/results/overlap.json):
steps per second (medians over interleaved rounds), halves_over_lockstep (median of
per-round ratios), and the main process's inference share of a lockstep step (the most overlap could hide).
"""

from __future__ import annotations

import argparse
import json
import os
import time
from pathlib import Path

import numpy as np
import torch

os.environ.setdefault("MUJOCO_GL", "egl")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--env", default="Hopper-v5")
    parser.add_argument("--num-envs", type=int, default=8)
    parser.add_argument("--steps", type=int, default=256, help="steps per env and round")
    parser.add_argument("--rounds", type=int, default=5)
    parser.add_argument("--out", default="runs/bench/overlap.json")
    args = parser.parse_args()
    torch.set_num_threads(1)

    from digail.algos.fast.inference import ActorCritic, CodeMLP
    from digail.envs.vector import SubprocVecEnv, cpu_count
    from digail.nets.critic import ValueNet
    from digail.nets.policy import ActionSpec
    from digail.nets.vae import HierarchicalPolicy

    n, half, cores = args.num_envs, args.num_envs // 2, cpu_count()
    whole = SubprocVecEnv(args.env, n, infos=False)
    halves = [SubprocVecEnv(args.env, half, workers=max(1, cores // 2), infos=False) for _ in range(2)]
    space = whole.single_action_space
    obs_dim = int(np.prod(whole.probe.observation_space.shape))
    model = HierarchicalPolicy(obs_dim, 4, ActionSpec.from_space(space))
    ac = ActorCritic(model.pi, ValueNet(obs_dim, 4), obs_dim)
    q = CodeMLP([model.q.net], obs_dim)
    rng = np.random.default_rng(0)
    low, high = space.low, space.high
    infer_s: list[float] = []

    def infer(obs: np.ndarray, prev: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        codes = q(obs, prev).argmax(-1)
        acts, _, _ = ac.sample(obs, codes, rng.standard_normal((len(obs), ac.act_dim), dtype=np.float32))
        return np.clip(acts, low, high), codes

    def lockstep() -> None:
        obs, _ = whole.reset(list(range(n)))
        prev = np.full(n, -1)
        t_inf = 0.0
        for _ in range(args.steps):
            t0 = time.perf_counter()
            acts, prev = infer(obs, prev)
            t_inf += time.perf_counter() - t0
            obs = whole.step(acts)[0]
        infer_s.append(t_inf)

    def overlapped() -> None:
        obs = [h.reset(list(range(i * half, (i + 1) * half)))[0] for i, h in enumerate(halves)]
        prev = [np.full(half, -1), np.full(half, -1)]
        for i in (0, 1):
            acts, prev[i] = infer(obs[i], prev[i])
            halves[i].step_async(acts)
        for _ in range(args.steps - 1):
            for i in (0, 1):
                obs[i] = halves[i].step_wait()[0]
                acts, prev[i] = infer(obs[i], prev[i])  # the other half steps meanwhile
                halves[i].step_async(acts)
        for h in halves:
            h.step_wait()

    runs = {"lockstep": lockstep, "halves": overlapped}
    samples: dict[str, list[float]] = {k: [] for k in runs}
    walls: list[float] = []
    for r in range(args.rounds):
        for name, fn in runs.items():
            t0 = time.perf_counter()
            fn()
            wall = time.perf_counter() - t0
            samples[name].append(n * args.steps / wall)
            if name == "lockstep":
                walls.append(wall)
        print(f"round {r + 1}: " + ", ".join(f"{k} {v[-1]:.0f}" for k, v in samples.items()), flush=True)
    whole.close()
    for h in halves:
        h.close()
    results = {"env": args.env, "num_envs": n, "steps_per_env": args.steps, "rounds": args.rounds, "cpus": cores,
               "loadavg": list(os.getloadavg()),
               **{f"{k}_sps": float(np.median(v)) for k, v in samples.items()},
               "halves_over_lockstep": float(np.median(np.array(samples["halves"]) / np.array(samples["lockstep"]))),
               "lockstep_inference_share": float(np.median(np.array(infer_s) / np.array(walls))),
               "samples": samples}
    Path(args.out).parent.mkdir(parents=True, exist_ok=True)
    Path(args.out).write_text(json.dumps(results, indent=2) + "\n")
    print(json.dumps({k: v for k, v in results.items() if k != "samples"}, indent=2))


if __name__ == "__main__":
    main()
