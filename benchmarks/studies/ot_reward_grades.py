"""Does the optimal-transport reward grade Fetch episodes? Held-out expert episodes against random-action ones.

    python benchmarks/studies/ot_reward_grades.py --vae runs/fetchfew/d4/bc_k4_s0 \
        --out benchmarks/studies/results/ot_reward_grades.json

The reward of `--train.imitation.reward ot` and `ot-subtask` against the first 4 demonstrations of
digail/fetchpickandplace/expert-v0, on Fetch's relative view through the VAE's normaliser (what the screen's
runs use), for the dataset's episodes 5-12 (expert episodes the reward never saw) and 8 episodes of uniform random
actions (env seeds 100-107, NumPy seed 0). Each episode is scored whole; its codes are q's causal segmentation
(`segment_many`), as the demonstrations' are. Prints and writes the mean reward per step of each episode.
"""

from __future__ import annotations

import argparse
import json
import os
from dataclasses import replace
from pathlib import Path
from typing import Any

import numpy as np
import torch

os.environ.setdefault("MUJOCO_GL", "egl")


def piece(trainer: Any, traj: Any, segment_many: Any) -> tuple[torch.Tensor, torch.Tensor, int, bool]:
    """A whole episode as the transport reward scores it: D's view of its states, q's codes, time 0, whole."""
    obs_n = trainer.model.normalizer(torch.as_tensor(np.asarray(traj.obs[:-1], np.float32)))
    codes = torch.as_tensor(segment_many(trainer.model, [traj])[0])
    return trainer.reward.inputs.features(obs_n).detach(), codes, 0, True


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--vae", type=Path, required=True, help="a K = 4 Fetch VAE run (fetch_fewdemo.sh 4 bc 0)")
    parser.add_argument("--out", type=Path, default=Path("benchmarks/studies/results/ot_reward_grades.json"))
    args = parser.parse_args()
    from digail.algos.decode import segment_many
    from digail.algos.directed_info_gail import build_trainer
    from digail.checkpoint import load_model
    from digail.commands.train import load_demos
    from digail.data.trajectory import Trajectory
    from digail.envs import make_env
    from digail.imitation_config import ImitationConfig
    from digail.preset import get_preset

    torch.set_num_threads(1)
    dataset = "digail/fetchpickandplace/expert-v0"
    demos, env_id = load_demos(dataset, episodes=4)
    held_out = load_demos(dataset, episodes=12)[0][4:12]
    env = make_env(env_id)
    rng = np.random.default_rng(0)
    random_eps = []
    for ep in range(8):
        obs, _ = env.reset(seed=100 + ep)
        seen, acts = [obs], []
        for _ in range(50):
            act = rng.uniform(-1, 1, env.action_space.shape).astype(np.float32)
            obs, *_ = env.step(act)
            seen.append(obs)
            acts.append(act)
        random_eps.append(Trajectory(obs=np.array(seen, np.float32), acts=np.array(acts)))
    env.close()
    base = get_preset("fetch").train
    out: dict[str, object] = {"vae": str(args.vae), "dataset": dataset, "demonstrations": 4,
                              "held_out_episodes": "5-12", "random_episodes": 8}
    for kind in ("ot", "ot-subtask"):
        model, _ = load_model(args.vae / "model.pt")
        cfg = replace(base, replay_fraction=0.0, closed_loop_codes="argmax", backend="sync",
                      imitation=ImitationConfig(reward=kind, disc_obs="relative"),
                      ppo=replace(base.ppo, num_envs=1, batch_size=64, minibatch_size=64))
        trainer = build_trainer(env_id, demos, cfg, vae_model=model, seed=0, run_dir=None, progress=False)
        try:
            reward = trainer.reward
            for name, eps in (("held_out_expert", held_out), ("random_actions", random_eps)):
                pieces = [piece(trainer, t, segment_many) for t in eps]
                per_episode = [round(float(r.mean()), 4) for r in reward.score(pieces)]  # type: ignore[attr-defined]
                out[f"{kind}_{name}"] = per_episode
                out[f"{kind}_{name}_mean"] = round(float(np.mean(per_episode)), 4)
                print(f"{kind:10s} {name:16s} mean {np.mean(per_episode):.3f}  {per_episode}", flush=True)
        finally:
            trainer.close()
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(json.dumps(out, indent=1) + "\n")
    print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
