"""Scripted pick-and-place controller for `digail/FetchPickAndPlace-v4` (paper section 5.4).

A proportional controller on the gripper position with four stages, the env's oracle phases
(`digail.envs.fetch.Phase`, tracked by the env itself from the state):

0. reach: move to 5 cm above the object with the fingers open;
1. grasp: descend onto the object, fingers open until the gripper is within 1 cm of the object's centre,
   then close them;
2. carry: keep the fingers closed and move so that the object (not the gripper) goes to the goal;
3. place: the same command, settling the object on the goal and holding it there until the episode ends.

An action is `[dx, dy, dz, grip]` in [-1, 1]; the env moves the gripper target by 5 cm per unit, so a gain of
10 halves the remaining distance at every step without overshooting. It succeeds on about every episode
(see `tests/test_fetch.py` and the data manifest for the measured rate).
"""

from __future__ import annotations

from typing import Any

import gymnasium as gym
import numpy as np

from digail.config import FINAL_EVAL_SEED
from digail.envs.fetch import FETCH_ENV_ID, GOAL, GRIP_POS, OBJECT_POS, FlatFetchPickAndPlace, Phase

GAIN = 10.0
"""proportional gain from position error (m) to action (1 unit = 5 cm)"""
HOVER = 0.05
"""height above the object the reach stage aims for (m)"""
CLOSE_WITHIN = 0.01
"""the grasp stage closes the fingers once the gripper is this close to the object's centre (m)"""
OPEN, CLOSE = 1.0, -1.0


def fetch_action(phase: int, obs: np.ndarray) -> np.ndarray:
    """The controller's action (float32, shape (4,)) for a flat observation and the current phase."""
    grip, obj, goal = obs[GRIP_POS], obs[OBJECT_POS], obs[GOAL]
    if phase == Phase.REACH:
        target, fingers = obj + np.array([0.0, 0.0, HOVER]), OPEN
    elif phase == Phase.GRASP:
        target = obj
        fingers = OPEN if np.linalg.norm(grip - obj) > CLOSE_WITHIN else CLOSE
    else:  # carry and place: move the held object onto the goal
        target, fingers = grip + (goal - obj), CLOSE
    move = np.clip(GAIN * (target - grip), -1.0, 1.0)
    return np.append(move, fingers).astype(np.float32)


def fetch_expert(env: gym.Env) -> np.ndarray:
    """Scripted expert action for the current state of a `digail/FetchPickAndPlace-v4` env (any wrappers)."""
    base = env.unwrapped
    if not isinstance(base, FlatFetchPickAndPlace):
        raise TypeError(f"fetch_expert drives FlatFetchPickAndPlace (digail/FetchPickAndPlace-v4), got "
                        f"{type(base).__name__}.")
    return fetch_action(base.phase, base.last_obs)


def evaluate_fetch_expert(episodes: int = 50, seed: int = FINAL_EVAL_SEED) -> dict[str, Any]:
    """Success rate and returns of the scripted controller over `episodes` episodes (episode i: seed + i).

    Also counts the episodes whose phase labels do not run 0 -> 1 -> 2 -> 3 one stage at a time.
    """
    from digail.envs import make_env
    from digail.envs.episodes import play_episodes

    env = make_env(FETCH_ENV_ID)
    eps = play_episodes(env, lambda env, obs: fetch_expert(env), episodes, seed, keep=True)
    successes = [bool(ep.final_info["is_success"]) for ep in eps]
    returns = [ep.ret for ep in eps]
    out_of_order = 0
    for ep in eps:
        labels = [info["subtask"] for info in ep.infos]
        steps = set(np.diff(labels).tolist())
        out_of_order += int(labels[0] != Phase.REACH or not steps <= {0, 1})
    env.close()
    return {"env_id": FETCH_ENV_ID, "episodes": episodes, "seed": seed,
            "success_rate": float(np.mean(successes)), "mean": float(np.mean(returns)),
            "std": float(np.std(returns)), "phase_order_violations": out_of_order}
