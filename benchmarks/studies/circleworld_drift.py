"""Why PPO fine-tuning loses Circle-World's drawing: the numbers behind the README's Circle-World paragraph.

    python benchmarks/studies/circleworld_drift.py VAE_RUN [--updates 25] [--episodes 50]

VAE_RUN is a `digail pretrain` run on digail/circleworld/expert-v0. Prints
1. how the radius of the drawn circle depends on the direction of the first step (geometry, no learning);
2. the deterministic closed-loop radius error after `--updates` PPO policy updates, starting from the VAE, for
   the discriminator's reward and for the env's own reward (minus the distance to the expert's reference point,
   so the signal is the true one), each at the paper's learning rate and at 1e-5 with noise 0.01
   (the preset's fine-tuning settings);
3. how much the discriminator's reward depends on the action direction after the critic warm-up: mean reward on
   the expert's states with the expert's actions rotated by a few degrees.
"""

from __future__ import annotations

import argparse
import math
from dataclasses import replace
from pathlib import Path
from typing import Any

import torch

from digail.algos.directed_info_gail import build_trainer
from digail.algos.rewards.discriminator import generator_reward
from digail.checkpoint import load_model
from digail.config import TrainConfig
from digail.data.minari_io import load_dataset
from digail.envs.circle_world import STEPS_PER_CIRCLE
from digail.eval.returns import run_episodes, task_metrics
from digail.preset import get_preset

ENV, DEMOS = "digail/CircleWorld-v0", "digail/circleworld/expert-v0"


def first_step_geometry() -> None:
    """The circle through the origin, centred on the y axis, through the point one step away at angle a."""
    expert = math.pi / STEPS_PER_CIRCLE  # the first chord's angle above the x axis, the same for every radius
    print("1. first step: direction error (degrees) -> radius of the circle the agent is then on / target")
    for err_deg in (-1.5, -0.5, -0.2, 0.0, 0.2, 0.5, 1.5):
        a = expert + math.radians(err_deg)
        # step length L = 2 r sin(pi / n); point (-L cos a, L sin a); circle radius (x^2 + y^2) / (2 y)
        ratio = 2 * math.sin(expert) / (2 * math.sin(a))
        print(f"   {err_deg:+5.1f} -> {ratio:.2f}")


def trainer_for(vae: Path, cfg: TrainConfig, seed: int, reward_fn: Any = None) -> Any:
    model, _ = load_model(vae / "model.pt")
    demos = list(load_dataset(DEMOS).trajs)
    return build_trainer(ENV, demos, cfg, vae_model=model, seed=seed, run_dir=None, progress=False,
                         reward_fn=reward_fn)


def radius_after(vae: Path, cfg: TrainConfig, updates: int, episodes: int, env_reward: bool) -> tuple[float, float]:
    """Deterministic closed-loop radius error before and after `updates` policy updates."""
    # with env_reward the env's own reward replaces D's: is the drift D's doing?
    trainer = trainer_for(vae, cfg, seed=0, reward_fn=(lambda logits, batch: batch["rews"]) if env_reward else None)
    before = task_metrics(run_episodes(trainer.model, ENV, episodes, 10_000, deterministic=True))["radius_error"]
    for _ in range(cfg.value_warmup + updates):
        trainer.iterate()
    after = task_metrics(run_episodes(trainer.model, ENV, episodes, 10_000, deterministic=True))["radius_error"]
    return before, after


def discriminator_direction_sensitivity(vae: Path, cfg: TrainConfig) -> None:
    trainer = trainer_for(vae, cfg, seed=0)
    for _ in range(cfg.value_warmup):
        trainer.iterate()
    obs, acts = trainer.expert.obs_n, trainer.expert.acts
    print(f"3. D's mean reward on expert states after {cfg.value_warmup} warm-up iterations, actions rotated by:")
    with torch.no_grad():
        for deg in (-10, -2, 0, 2, 10):
            c, s = math.cos(math.radians(deg)), math.sin(math.radians(deg))
            rot = torch.stack([c * acts[:, 0] - s * acts[:, 1], s * acts[:, 0] + c * acts[:, 1]], -1)
            logits = trainer.reward.disc(obs, trainer.act_input(rot))
            reward = generator_reward(logits, cfg.imitation.logits_to_reward)
            print(f"   {deg:+4d} deg: {float(reward.mean()):.4f}")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("vae", type=Path)
    parser.add_argument("--updates", type=int, default=25)
    parser.add_argument("--episodes", type=int, default=50)
    args = parser.parse_args()
    torch.set_num_threads(1)
    preset = get_preset("circle-world").train
    paper = replace(preset, min_init_log_std=-2.3, ppo=replace(preset.ppo, policy_lr=None, anneal_lr=False))
    fine = replace(preset, ppo=replace(preset.ppo, anneal_lr=False))
    first_step_geometry()
    print(f"2. radius error of the deterministic policy before -> after {args.updates} PPO policy updates")
    for name, cfg in (("lr 3e-4, noise 0.1", paper), ("lr 1e-5, noise 0.01", fine)):
        for env_reward in (False, True):
            before, after = radius_after(args.vae, cfg, args.updates, args.episodes, env_reward)
            reward = "env reward" if env_reward else "D reward  "
            print(f"   {name}, {reward}: {before:.3f} -> {after:.3f}", flush=True)
    discriminator_direction_sensitivity(args.vae, paper)


if __name__ == "__main__":
    main()
