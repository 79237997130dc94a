"""Training throughput on one machine, in one run: env alone, rollouts, full DI-GAIL, Stable-Baselines3 PPO.

    python benchmarks/throughput.py [--env Hopper-v5] [--num-envs 8] [--batch 4096] [--iterations 3] [--rounds 5]

Writes runs/bench/throughput.json (`--out`; what `make bench` runs; the published measurements are
benchmarks/results/speed/throughput*.json, copied there on purpose) with environment steps per second:
- random_sps: the single-process vector env stepping random actions (the one-core ceiling of the old trainer);
  random_sps_<backend>: the same on every training backend (`digail.envs.vector`);
- rollout_sps: digail's rollout on the single-process (sync) env (macro-policy q + sub-task policy pi + value), no
  learning: the one-core limit any single-process trainer is held under;
- train_sps_<backend>: full Directed-Info GAIL iterations (rollout, discriminator, reward relabelling, PPO epochs)
  on each available backend (sync, subproc, envpool), with the PPO loss compiled where the env's preset compiles
  it (Hopper does); train_sps is the fastest of them and train_backend names it;
- train_over_own_rollouts_<backend>: the training iterations' rollout time over their total time;
- sb3_ppo_sps: Stable-Baselines3 PPO with the same envs (DummyVecEnv, one process), batch, epochs, minibatch and
  64x64 networks;
- train_over_sync_<backend>: each backend's training throughput over the sync backend's (e.g. Fetch: subproc
  against sync);
- vae_demo_sps: VAE pre-training's ELBO epochs (`digail.algos.vae_pretrain.pretrain`, the env preset's settings
  without its hard-EM start, no polish: the paper's VAE, 2000 epochs on Hopper) in demonstration steps per
  second: epochs x steps in the demonstrations / time, on the env's shipped demonstrations where there are some
  (vae_demos names them), else the random ones below. The hard-EM start is a fixed number of fitting steps
  (`--vae.init-steps`), not per epoch: benchmarks/studies/vae_speed.py times it.
cpus is the cores this process may use and loadavg the machine's load when the run started (other jobs share it).
Absolute numbers drift by +-25% on a shared 2-core machine; the ratios measured in one run are what to quote.
Demonstrations are random-action rollouts: throughput does not depend on their quality.
"""

from __future__ import annotations

import argparse
import copy
import json
import os
import platform
import time
from pathlib import Path

import numpy as np
import torch

os.environ.setdefault("MUJOCO_GL", "egl")


def random_demos(env_id: str, episodes: int, seed: int = 0):  # type: ignore[no-untyped-def]
    from digail.data.trajectory import Trajectory
    from digail.envs import make_env

    env = make_env(env_id)
    env.action_space.seed(seed)
    out = []
    for e in range(episodes):
        o, _ = env.reset(seed=seed + e)
        obs, acts = [o], []
        while True:
            a = env.action_space.sample()
            o, _, term, trunc, _ = env.step(a)
            obs.append(o)
            acts.append(a)
            if term or trunc or len(acts) >= 200:
                break
        out.append(Trajectory(np.asarray(obs, np.float32), np.asarray(acts, np.float32), terminated=bool(term)))
    env.close()
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--env", default="Hopper-v5")
    parser.add_argument("--num-envs", type=int, default=8)
    parser.add_argument("--batch", type=int, default=4096)
    parser.add_argument("--minibatch", type=int, default=512)
    parser.add_argument("--epochs", type=int, default=10)
    parser.add_argument("--iterations", type=int, default=3)
    parser.add_argument("--codes", type=int, default=4)
    parser.add_argument("--rounds", type=int, default=5, help="interleaved repetitions; medians are reported")
    parser.add_argument("--vae-epochs", type=int, default=2, help="VAE pre-training epochs per round")
    parser.add_argument("--out", default="runs/bench/throughput.json")
    args = parser.parse_args()
    torch.set_num_threads(1)

    import digail
    from digail.algos.directed_info_gail import DirectedInfoGAIL
    from digail.config import PPOConfig, TrainConfig
    from digail.envs.registry import preset_for
    from digail.nets.policy import ActionSpec
    from digail.nets.vae import HierarchicalPolicy

    steps = args.batch * args.iterations
    results: dict[str, object] = {"env": args.env, "num_envs": args.num_envs, "batch": args.batch,
                                  "minibatch": args.minibatch, "epochs": args.epochs, "iterations": args.iterations,
                                  "rounds": args.rounds, "codes": args.codes, "torch_threads": 1,
                                  "machine": platform.machine(), "cpus": len(os.sched_getaffinity(0)),
                                  "digail": digail.__version__}

    from digail.envs.registry import env_spec
    from digail.envs.vector import envpool_available, make_vec_env

    spec = env_spec(args.env)
    backends = ["sync", "subproc"] + (["envpool"] if envpool_available() and spec and spec.envpool else [])
    results["backends"] = backends
    results["loadavg"] = list(os.getloadavg())

    # the env alone, on every backend
    venvs = {b: make_vec_env(args.env, args.num_envs, b, infos=False) for b in backends}
    space = venvs["sync"].single_action_space
    space.seed(0)
    acts = np.stack([space.sample() for _ in range(args.num_envs)])
    for v in venvs.values():
        v.reset(list(range(args.num_envs)))

    def random_steps(backend: str):  # type: ignore[no-untyped-def]
        def run() -> None:
            for _ in range(steps // args.num_envs):
                venvs[backend].step(acts)
        return run

    # digail rollouts and full iterations (an untrained K-code model: speed does not depend on the weights)
    demos = random_demos(args.env, 20)
    obs_dim = demos[0].obs.shape[1]
    model = HierarchicalPolicy(obs_dim, args.codes, ActionSpec.from_space(space))
    model.normalizer.fit(np.concatenate([t.obs for t in demos]))
    # compile as the env's preset does (the MuJoCo presets compile the PPO loss)
    compile_loss = preset_for(args.env).train.ppo.compile
    ppo = PPOConfig(num_envs=args.num_envs, batch_size=args.batch, epochs=args.epochs,
                    minibatch_size=args.minibatch, compile=compile_loss)
    results["compile"] = compile_loss
    trainers = {}
    for b in backends:
        # value_warmup=0: every measured iteration updates the policy too (the warm-up would skip its backward)
        cfg = TrainConfig(iterations=args.iterations, ppo=ppo, disc_minibatch_size=args.minibatch, value_warmup=0,
                          backend=b)  # type: ignore[arg-type]
        trainers[b] = DirectedInfoGAIL(args.env, demos, copy.deepcopy(model), cfg, seed=0, progress=False)
        t0 = time.perf_counter()
        trainers[b].iterate()  # warm-up, as SB3 gets below: first resets, allocations, the loss's compile
        results[f"warmup_iteration_s_{b}"] = time.perf_counter() - t0

    def rollouts() -> None:
        for _ in range(args.iterations):
            trainers["sync"].learner.collect()

    shares: dict[str, list[float]] = {b: [] for b in backends}  # per round: rollout share of the iterations' time

    def train(backend: str):  # type: ignore[no-untyped-def]
        def run() -> None:
            t_rollout = t_total = 0.0
            for _ in range(args.iterations):
                out = trainers[backend].iterate()
                t_rollout += 1.0 / out["perf/rollout_sps"]
                t_total += 1.0 / out["perf/sps"]
            shares[backend].append(t_rollout / t_total)
        return run

    # Stable-Baselines3 PPO at matched settings
    from stable_baselines3 import PPO
    from stable_baselines3.common.env_util import make_vec_env as sb3_make_vec_env

    sb3_env = sb3_make_vec_env(args.env, n_envs=args.num_envs, seed=0)
    model_sb3 = PPO("MlpPolicy", sb3_env, n_steps=args.batch // args.num_envs, batch_size=args.minibatch,
                    n_epochs=args.epochs, policy_kwargs=dict(net_arch=[64, 64]), device="cpu", seed=0, verbose=0)
    model_sb3.learn(total_timesteps=args.batch)  # warm-up iteration

    def sb3() -> None:
        model_sb3.learn(total_timesteps=steps, reset_num_timesteps=False)

    # VAE pre-training on the env's demonstrations at its preset's settings
    from dataclasses import replace

    from digail.algos.vae_pretrain import pretrain
    from digail.data.demos import default_dataset_id
    from digail.data.minari_io import load_dataset, shipped_dataset_ids

    vae_id = default_dataset_id(args.env)
    vae_trajs = list(load_dataset(vae_id).trajs) if vae_id in shipped_dataset_ids() else demos
    results["vae_demos"] = vae_id if vae_trajs is not demos else "random"
    vae_cfg = replace(preset_for(args.env).vae, init="none", epochs=args.vae_epochs, polish_steps=0)
    vae_steps = args.vae_epochs * sum(len(t) for t in vae_trajs)
    pretrain(vae_trajs, replace(vae_cfg, epochs=1), progress=False)  # warm-up

    def vae() -> None:
        pretrain(vae_trajs, vae_cfg, progress=False)

    # Rounds interleave the measurements so that drifting load on a shared machine hits all of them alike.
    runs = {"random_sps": random_steps("sync"), "rollout_sps": rollouts, "sb3_ppo_sps": sb3, "vae_demo_sps": vae}
    for b in backends:
        if b != "sync":
            runs[f"random_sps_{b}"] = random_steps(b)
        runs[f"train_sps_{b}"] = train(b)
    samples: dict[str, list[float]] = {k: [] for k in runs}
    for r in range(args.rounds):
        for name, fn in runs.items():
            t0 = time.perf_counter()
            fn()
            samples[name].append((vae_steps if name == "vae_demo_sps" else steps) / (time.perf_counter() - t0))
        print(f"round {r + 1}: " + ", ".join(f"{k} {v[-1]:.0f}" for k, v in samples.items()), flush=True)
    for name, vals in samples.items():
        results[name] = float(np.median(vals))
    results["samples"] = samples
    for v in venvs.values():
        v.close()
    for t in trainers.values():
        t.close()

    # Ratios within a round share its load; their median is steadier than a ratio of medians.
    def ratio(a: str, b: str) -> float:
        return float(np.median(np.array(samples[a]) / np.array(samples[b])))

    best = max(backends, key=lambda b: results[f"train_sps_{b}"])  # type: ignore[arg-type,return-value]
    results["train_backend"] = best
    results["train_sps"] = results[f"train_sps_{best}"]
    results["train_over_sb3"] = ratio(f"train_sps_{best}", "sb3_ppo_sps")
    results["train_over_rollout"] = ratio(f"train_sps_{best}", "rollout_sps")
    results["rollout_over_random"] = ratio("rollout_sps", "random_sps")
    for b in backends:
        results[f"train_over_sb3_{b}"] = ratio(f"train_sps_{b}", "sb3_ppo_sps")
        results[f"train_over_rollout_{b}"] = ratio(f"train_sps_{b}", "rollout_sps")
        # the rollout's share of the training iterations' own time
        results[f"train_over_own_rollouts_{b}"] = float(np.median(shares[b]))
        results["samples"][f"train_over_own_rollouts_{b}"] = shares[b]  # type: ignore[index]
        if b != "sync":
            results[f"random_over_random_sync_{b}"] = ratio(f"random_sps_{b}", "random_sps")
            results[f"train_over_sync_{b}"] = ratio(f"train_sps_{b}", "train_sps_sync")
    results["targets_met"] = {"train_over_sb3>=2.5": results["train_over_sb3"] >= 2.5,  # type: ignore[operator]
                              "train_over_rollout>=1.5": results["train_over_rollout"] >= 1.5}  # type: ignore[operator]
    results["note"] = ("medians over interleaved rounds; train_sps counts DI-GAIL's extra work (discriminator, q, "
                       "bonus) that SB3 PPO does not do; quote ratios from one run, absolute numbers drift +-25% on "
                       "a shared machine (loadavg: the machine's load when the run started, other jobs included).")
    Path(args.out).parent.mkdir(parents=True, exist_ok=True)
    Path(args.out).write_text(json.dumps(results, indent=2) + "\n")
    print(json.dumps({k: round(v, 3) if isinstance(v, float) else v for k, v in results.items()}, indent=2))


if __name__ == "__main__":
    main()
