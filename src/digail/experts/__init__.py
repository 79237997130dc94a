"""The project's experts: scripted controllers for its own envs and Fetch, Stable-Baselines3-trained ones for MuJoCo.

`expert_for(env_id)` is the one place that picks an env's expert, for recording demonstrations and for measuring the
expert the same way as the agent.
"""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path
from typing import Any

import gymnasium as gym
import numpy as np

from digail.errors import UserError

Policy = Callable[[gym.Env, Any], Any]
"""An expert as rollouts use it: (env, current observation) -> action."""


def expert_for(env_id: str, path: str | Path | None = None) -> tuple[Policy, str]:
    """The expert of `env_id` and the name of its kind ("scripted" or "rl").

    With `path` the RL expert stored there is used, even for envs with a scripted expert; otherwise the scripted
    expert where one exists, else the shipped RL expert.

    Raises:
        UserError: no expert for `env_id`, or the RL experts' dependencies are missing.
    """
    if path is None:
        from digail.experts.scripted import get_scripted_expert

        scripted = get_scripted_expert(env_id)
        if scripted is not None:
            return (lambda env, obs: scripted(env)), "scripted"
    try:
        from digail.experts.rl import load_expert
    except ImportError as exc:
        raise UserError(f"no scripted expert for {env_id} and the RL experts are unavailable ({exc}); "
                        "install the rl extra (`pip install digail[rl]`).") from exc
    policy = load_expert(env_id, None if path is None else Path(path))
    return (lambda env, obs: policy(np.asarray(obs, dtype=np.float32)[None])[0]), "rl"
