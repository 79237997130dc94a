"""Videos of evaluation episodes (rgb_array rendering; MuJoCo headless via MUJOCO_GL=egl)."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
import torch

from digail.nets.mlp import one_hot


@torch.no_grad()
def record_video(model, env_id: str, path: Path, seed: int = 0, episodes: int = 1, fps: int = 30) -> Path:  # type: ignore[no-untyped-def]
    """Roll out the closed-loop hierarchical policy and write an mp4 of `episodes` episodes."""
    import imageio.v2 as imageio

    from digail.envs import make_env
    from digail.envs.episodes import play_episode

    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    env = make_env(env_id, render_mode="rgb_array")
    frames: list[Any] = []
    prev = torch.tensor([-1])

    def act(env: Any, obs: Any) -> np.ndarray:
        nonlocal prev
        frames.append(np.asarray(env.render()))
        obs_n = model.normalizer(torch.as_tensor(np.asarray(obs, np.float32))[None])
        code = model.q(obs_n, one_hot(prev, model.codes)).argmax(-1)
        prev = code
        return model.pi.mode(obs_n, torch.eye(model.codes)[code])[0].numpy()

    for e in range(episodes):
        prev = torch.tensor([-1])
        play_episode(env, act, seed + e)
    env.close()
    imageio.mimsave(path, frames, fps=fps)
    return path
