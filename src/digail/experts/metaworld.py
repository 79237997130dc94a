"""Meta-World's own scripted experts (`metaworld.policies`, one per task) as digail experts.

Each is a proportional controller whose target comes from an if/elif chain over distances in its `_desired_pos`
(one return per phase) and whose gripper effort from a second test. The env (`digail.envs.metaworld.MetaWorldEnv`)
holds the task's expert and reports its phase at every observation in `info["subtask"]`, so demonstrations
recorded with it carry the phase the expert was in when it chose each action. The expert's warning that its gain
exceeds the action bounds (it is clipped) is silenced.
"""

from __future__ import annotations

import gymnasium as gym
import numpy as np

from digail.envs.metaworld import EPISODE_STEPS, MetaWorldEnv, env_id


def metaworld_expert(env: gym.Env) -> np.ndarray:
    """The task's scripted expert action (float32, shape (4,)) for the current state of a `metaworld/<task>` env."""
    base = env.unwrapped
    if not isinstance(base, MetaWorldEnv):
        raise TypeError(f"metaworld_expert drives MetaWorldEnv (metaworld/<task>-v3), got {type(base).__name__}.")
    return base.expert.action(base.last_obs)


METAWORLD_EXPERTS = {env_id(task): metaworld_expert for task in EPISODE_STEPS}
"""env id -> expert, for every Meta-World task"""
