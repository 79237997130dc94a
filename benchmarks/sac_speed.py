"""Soft actor-critic throughput: digail's off-policy learner against Stable-Baselines3's SAC, side by side.

    python benchmarks/sac_speed.py [--env Hopper-v5] [--sizes 64 256 64:256] [--steps 300] [--rounds 2]

One torch thread, one environment, one update of batch 256 per environment step (update-to-data ratio 1), after a
warm-up that fills the buffer past the learning start. A size H gives the actor, both critics (and D) hidden
layers HxH in both libraries; P:Q gives the actor (and D) PxP and the critics QxQ (the training runs' 64:256).
Each round times every variant in turn, so that drifting load on a shared machine hits all of them alike; the
medians over the rounds and their ratios go to benchmarks/results/speed/sac_speed.json. Every variant is timed by the
wall clock (`*_sps_H`) and by this process's CPU time (`*_cpu_sps_H`, steps per CPU second): on a machine shared
with other jobs the wall clock also counts the time the process waited for a core, the CPU time does not (it still
grows somewhat with load: caches and the core's other hardware thread are shared):

- sb3_sps_H: Stable-Baselines3 SAC (MlpPolicy, net_arch pi [P, P] and qf [Q, Q], train_freq 1, gradient_steps 1);
- ours_sps_H: digail's SAC on the env's own reward (`--train.learner sac`, no discriminator updates): the work per
  step of SB3's, plus D's logits on the batch (its relabelling, which this reward ignores: one forward pass of D);
- ours_gail_sps_H: the same with GAIL's discriminator updated every step (gradient penalty on) and its reward
  relabelled on every batch: what `digail train --train.learner sac` runs;
- ours_autograd_sps_H: digail's SAC with autograd instead of its hand-written gradients (`digail.algos.fast.sac_grad`);
- update_flops_H: the floating-point operations of the matrix products of one SAC update (`update_matmuls`), and
  matmul_bound_cpu_sps_H the updates per CPU second if an update were those products alone (`matmul_bound`);
- speedup_H = ours_sps_H / sb3_sps_H, speedup_gail_H = ours_gail_sps_H / sb3_sps_H, and `cpu_` the same by CPU
  time.

Both libraries run with the malloc policy of `digail.utils.keep_heap_pages` (digail's SAC loop sets it for its
process; here it is set before anything runs, so SB3 runs with it too).
The demonstrations are the env's shipped ones (only D sees them); throughput does not depend on their quality.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import time
from pathlib import Path
from typing import Any

import numpy as np
import torch

os.environ.setdefault("MUJOCO_GL", "egl")

BATCH = 256
WARMUP = 300
"""environment steps before the first update (both libraries), and then untimed updates before the clock starts"""


def _sizes(spec: str) -> tuple[int, int]:
    """"H" -> (H, H); "P:Q" -> (P, Q): the actor's (and D's) and the critics' hidden width."""
    pi, _, q = spec.partition(":")
    return int(pi), int(q or pi)


def _timed(step: Any) -> Any:
    """A function running `step(steps)` and returning (steps per wall second, steps per CPU second)."""
    def run(steps: int) -> tuple[float, float]:
        w0, c0 = time.perf_counter(), time.process_time()
        step(steps)
        return steps / (time.perf_counter() - w0), steps / max(time.process_time() - c0, 1e-9)

    return run


def sb3_runner(env_id: str, spec: str, seed: int = 0) -> Any:
    """A function timing `steps` SAC steps of Stable-Baselines3 (after its warm-up)."""
    import gymnasium as gym
    from stable_baselines3 import SAC

    pi, q = _sizes(spec)
    model = SAC("MlpPolicy", gym.make(env_id), policy_kwargs=dict(net_arch=dict(pi=[pi, pi], qf=[q, q])),
                batch_size=BATCH, learning_starts=WARMUP, train_freq=1, gradient_steps=1, buffer_size=100_000,
                device="cpu", seed=seed, verbose=0)
    model.learn(total_timesteps=2 * WARMUP)
    return _timed(lambda steps: model.learn(total_timesteps=steps, reset_num_timesteps=False))


def ours_runner(env_id: str, spec: str, *, gail: bool, hand: bool = True, seed: int = 0) -> Any:
    """A function timing `steps` SAC steps of digail's learner (GAIL's D on or off) after its warm-up."""
    from digail.algos.directed_info_gail import build_trainer
    from digail.commands.train import load_demos
    from digail.config import SACConfig, TrainConfig
    from digail.data.demos import default_dataset_id
    from digail.imitation_config import ImitationConfig

    pi, q = _sizes(spec)
    demos, _ = load_demos(default_dataset_id(env_id), env_id, episodes=4)
    sac = SACConfig(steps_per_iteration=WARMUP, learning_starts=WARMUP, batch_size=BATCH, hidden=(q, q),
                    policy_warmup=0, buffer_size=100_000)
    cfg = TrainConfig(method="gail", learner="sac", hidden=(pi, pi), backend="sync", sac=sac,
                      imitation=ImitationConfig(disc_every=1 if gail else 0))
    reward_fn = None if gail else (lambda logits, batch: batch["rews"])
    trainer = build_trainer(env_id, demos, cfg, vae_model=None, seed=seed, run_dir=None, progress=False,
                            reward_fn=reward_fn)
    loop = trainer.learner
    loop.sac.hand = hand and loop.sac.hand
    trainer.iterate()
    trainer.iterate()

    def steps_of(steps: int) -> None:
        for _ in range(steps):
            loop.step_and_update()

    return _timed(steps_of)


def update_matmuls(env_id: str, spec: str) -> list[tuple[int, int, int]]:
    """The (m, k, n) matrix products of one SAC update of digail's (batch 256, no D step): the arithmetic any SAC
    update must do with these nets. Both critics count separately; elementwise work is left out."""
    import gymnasium as gym

    env = gym.make(env_id)
    obs, act = int(np.prod(env.observation_space.shape or (1,))), int(np.prod(env.action_space.shape or (1,)))
    env.close()
    p, q, b = *_sizes(spec), BATCH
    codes = 1  # GAIL: one code
    pi_fwd = [(b, obs + codes, p), (b, p, p), (b, p, act)]
    q_fwd = 2 * [(b, obs + codes + act, q), (b, q, q), (b, q, 1)]
    critic_bwd = 2 * [(q, b, 1), (b, 1, q), (q, b, q), (b, q, q), (obs + codes + act, b, q)]  # weight, input grads
    to_action = 2 * [(b, 1, q), (b, q, q), (b, q, act)]  # the policy's gradient back through the critics
    pi_bwd = [(act, b, p), (b, act, p), (p, b, p), (b, p, p), (p, b, obs + codes)]
    return pi_fwd + 2 * q_fwd + critic_bwd + pi_fwd + q_fwd + to_action + pi_bwd


def matmul_bound(shapes: list[tuple[int, int, int]], rounds: int = 20, dtype: torch.dtype = torch.float32) -> float:
    """Updates per CPU second if an update were only these matrix products with operands of `dtype` (one thread,
    best of `rounds`): an upper bound of any SAC implementation's rate with these nets on this machine."""
    mats = [(torch.randn(m, k).to(dtype), torch.randn(k, n).to(dtype)) for m, k, n in shapes]
    best = float("inf")
    for _ in range(rounds):
        c0 = time.process_time()
        for _ in range(10):
            for a, w in mats:
                torch.mm(a, w)
        best = min(best, (time.process_time() - c0) / 10)
    return 1.0 / best


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--env", default="Hopper-v5")
    parser.add_argument("--sizes", nargs="+", default=["64", "256", "64:256"],
                        help="H (every net HxH) or P:Q (actor and D PxP, critics QxQ)")
    parser.add_argument("--steps", type=int, default=300)
    parser.add_argument("--rounds", type=int, default=2)
    parser.add_argument("--out", default="benchmarks/results/speed/sac_speed.json")
    args = parser.parse_args()
    from digail.utils import keep_heap_pages, set_torch_threads

    set_torch_threads(1)
    # digail's SAC loop sets this malloc policy when it starts; set here first, it holds for SB3's runs as well
    heap_kept = keep_heap_pages()
    result: dict[str, Any] = {"env": args.env, "steps_per_measure": args.steps, "rounds": args.rounds,
                              "batch_size": BATCH, "torch_threads": torch.get_num_threads(),
                              "torch": torch.__version__, "machine": platform.processor() or platform.machine(),
                              "loadavg_start": os.getloadavg()[0], "heap_pages_kept": heap_kept}
    import stable_baselines3

    result["sb3"] = stable_baselines3.__version__
    for h in args.sizes:
        runners = {f"sb3_sps_{h}": sb3_runner(args.env, h), f"ours_sps_{h}": ours_runner(args.env, h, gail=False),
                   f"ours_gail_sps_{h}": ours_runner(args.env, h, gail=True),
                   f"ours_autograd_sps_{h}": ours_runner(args.env, h, gail=False, hand=False)}
        samples: dict[str, list[tuple[float, float]]] = {k: [] for k in runners}
        for r in range(args.rounds):
            for key, run in runners.items():
                samples[key].append(run(args.steps))
                wall, cpu = samples[key][-1]
                print(f"round {r}: {key} {wall:.1f} steps/s, {cpu:.1f} steps per CPU second", flush=True)
        for key, vals in samples.items():
            cpu_key = key.replace("_sps_", "_cpu_sps_")
            result[key] = float(np.median([w for w, _ in vals]))
            result[key + "_samples"] = [round(w, 2) for w, _ in vals]
            result[cpu_key] = float(np.median([c for _, c in vals]))
            result[cpu_key + "_samples"] = [round(c, 2) for _, c in vals]
        for kind in ("", "cpu_"):
            sb3 = result[f"sb3_{kind}sps_{h}"]
            result[f"{kind}speedup_{h}"] = result[f"ours_{kind}sps_{h}"] / sb3
            result[f"{kind}speedup_gail_{h}"] = result[f"ours_gail_{kind}sps_{h}"] / sb3
            result[f"{kind}hand_over_autograd_{h}"] = (result[f"ours_{kind}sps_{h}"]
                                                       / result[f"ours_autograd_{kind}sps_{h}"])
        shapes = update_matmuls(args.env, h)
        result[f"update_flops_{h}"] = 2 * sum(m * k * n for m, k, n in shapes)
        result[f"matmul_bound_cpu_sps_{h}"] = matmul_bound(shapes)
        print({k: round(v, 3) for k, v in result.items() if k.endswith(f"_{h}")}, flush=True)
    result["loadavg_end"] = os.getloadavg()[0]
    Path(args.out).parent.mkdir(parents=True, exist_ok=True)
    Path(args.out).write_text(json.dumps(result, indent=2) + "\n")
    print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
