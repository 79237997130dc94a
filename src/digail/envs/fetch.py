"""`digail/FetchPickAndPlace-v4`: Fetch pick-and-place with a flat observation and oracle phase labels.

gymnasium-robotics' `FetchPickAndPlace-v4` observes a dict (`observation`, `achieved_goal`, `desired_goal`).
The policies here take flat vectors, and the goal must be part of the state (the paper's Fetch policies are
goal-conditioned), so this env wraps it and observes `concat(observation, desired_goal)`, 28 float64 numbers:

| slice   | content                                                         |
| ------- | --------------------------------------------------------------- |
| 0:3     | gripper position (world x, y, z, metres)                        |
| 3:6     | object position                                                 |
| 6:9     | object position relative to the gripper (object - gripper)      |
| 9:11    | finger joint positions (each ~0.05 open, ~0.024 holding the cube) |
| 11:14   | object rotation (Euler angles)                                  |
| 14:17   | object linear velocity relative to the gripper (per env step)   |
| 17:20   | object angular velocity (per env step)                          |
| 20:23   | gripper linear velocity (per env step)                          |
| 23:25   | finger joint velocities (per env step)                          |
| 25:28   | desired goal: target position of the object                     |

`achieved_goal` is dropped: it equals the object position (3:6). Actions, the sparse reward (-1 until the
object is within 5 cm of the goal, then 0), `info["is_success"]` and the 50-step time limit are the
original's.

**Task measures** in every step's info, for evaluation only (the learner never sees an env reward):

- `dense_reward`: minus the object-to-goal distance after the step, the reward of the original's `dense`
  variant; summed over the 50 steps it is the paper's Table 2 return;
- `grasped`: both fingers touch the object (MuJoCo contacts), i.e. it is held between them; "grasped at
  some step" is the grasp rate. (Not "lifted off the table": for a goal on the table the scripted expert
  slides the held cube there without raising it more than a millimetre.)
- `lifted`: the object is more than `LIFTED` above the height it rests at on the table (a pushed or tipped
  cube stays below); "lifted at some step" is the lift rate.

`is_success` of the last step's info (object within 5 cm of the goal at the end) is the success rate.
The registry entry (`digail.envs.registry.ENV_SPECS`) declares how evaluation aggregates them.

**Oracle phase** in `info["subtask"]` (at reset and after every step): the stage of the pick-and-place
task the current state is in, 0 reach, 1 grasp, 2 carry, 3 place. It is tracked from the state alone, moving
at most one stage forward per step and never back within an episode, so every episode's labels run
0 -> 1 -> 2 -> 3 in order (as far as it gets):

- reach -> grasp: the gripper is centred above the object (within 1 cm horizontally, 0-8 cm above it);
- grasp -> carry: the gripper is on the object (within 2 cm) with the fingers closed on it;
- carry -> place: the object is within 2 cm of the goal (place = settle and hold it there).

The scripted controller `digail.experts.fetch.fetch_expert` acts on exactly these phases, so for its
demonstrations the label is the phase the expert was in when it chose the action.

gymnasium-robotics is imported only when this env is made, so `import digail` works without it.
"""

from __future__ import annotations

from enum import IntEnum
from typing import Any

import gymnasium as gym
import numpy as np

FETCH_ENV_ID = "digail/FetchPickAndPlace-v4"
FETCH_RELATIVE_ENV_ID = "digail/FetchPickAndPlaceRelative-v4"
"""the same task observed in the relative view (`RelativeFetchPickAndPlace`)"""
INNER_ENV_ID = "FetchPickAndPlace-v4"
MAX_EPISODE_STEPS = 50

GRIP_POS = slice(0, 3)
OBJECT_POS = slice(3, 6)
OBJECT_REL_POS = slice(6, 9)
FINGERS = slice(9, 11)
GOAL = slice(25, 28)
OBS_DIM = 28


class Phase(IntEnum):
    """Stages of pick-and-place, the oracle sub-task labels."""

    REACH = 0
    GRASP = 1
    CARRY = 2
    PLACE = 3


ABOVE_OBJECT_XY = 0.01
"""reach -> grasp: horizontal gripper-object distance below this (m)"""
ABOVE_OBJECT_Z = (0.0, 0.08)
"""reach -> grasp: gripper height above the object within this range (m)"""
ON_OBJECT = 0.02
"""grasp -> carry: gripper-object distance below this (m)"""
FINGERS_CLOSED = 0.053
"""grasp -> carry: summed finger opening below this (fully open ~0.10, holding the 5 cm cube ~0.048)"""
AT_GOAL = 0.02
"""carry -> place: object-goal distance below this (m); success needs < 0.05"""
LIFTED = 0.02
"""`info["lifted"]`: object centre this far above its resting height (m); tipping the 5 cm cube onto an edge
raises it ~1 cm"""


def next_phase(phase: int, obs: np.ndarray) -> int:
    """Advance the phase tracker by at most one stage given the flat observation `obs` (see module doc)."""
    grip, obj, goal = obs[GRIP_POS], obs[OBJECT_POS], obs[GOAL]
    if phase == Phase.REACH:
        height = grip[2] - obj[2]
        above = np.linalg.norm(grip[:2] - obj[:2]) < ABOVE_OBJECT_XY
        return int(Phase.GRASP) if above and ABOVE_OBJECT_Z[0] < height < ABOVE_OBJECT_Z[1] else phase
    if phase == Phase.GRASP:
        holding = np.linalg.norm(grip - obj) < ON_OBJECT and float(obs[FINGERS].sum()) < FINGERS_CLOSED
        return int(Phase.CARRY) if holding else phase
    if phase == Phase.CARRY:
        return int(Phase.PLACE) if np.linalg.norm(obj - goal) < AT_GOAL else phase
    return phase


def task_info(obs: np.ndarray, rest_height: float, grasped: bool) -> dict[str, Any]:
    """The task measures of a flat observation (module doc): `dense_reward`, `grasped` (given) and `lifted`."""
    obj = obs[OBJECT_POS]
    return {"dense_reward": -float(np.linalg.norm(obj - obs[GOAL])), "grasped": bool(grasped),
            "lifted": bool(obj[2] - rest_height > LIFTED)}


def _relative_parts(obs: Any) -> list[Any]:
    """The relative view's pieces of flat observations (n, 28), NumPy or torch alike."""
    return [obs[:, 6:9], obs[:, 25:28] - obs[:, 3:6], obs[:, 2:3], obs[:, 5:6], obs[:, 9:25]]


RELATIVE_DIM = 24


def relative_view(obs: Any) -> Any:
    """What a discriminator sees of flat observations (n, 28) under `--train.imitation.disc-obs relative`: the object
    from the gripper, the goal from the object, the heights of gripper and object, and fingers, rotation and velocities
    (n, 24) - no horizontal position of gripper, object or goal, so that D cannot tell a few demonstrations from
    the agent by where their objects and goals happened to lie. Takes and returns torch tensors."""
    import torch

    return torch.cat(_relative_parts(obs), -1)


def placing_view(obs: Any) -> Any:
    """The relative view without rotation and velocities (n, 10): the object from the gripper, the goal from the
    object, the heights of gripper and object, and the fingers - where things are, so that a transport cost between
    steps is not dominated by how fast they move. For `--train.imitation.disc-obs digail.envs.fetch:placing_view`."""
    import torch

    return torch.cat([*_relative_parts(obs)[:4], obs[:, 9:11]], -1)


def _norm(x: Any) -> Any:
    """Lengths of the rows of a torch tensor (n, k) -> (n, 1)."""
    return x.norm(dim=-1, keepdim=True)


def _distances_rest(obs: Any) -> list[Any]:
    """What the distances views keep beside the two distances: the goal's height above the object, the heights of
    gripper and object, the fingers and the gripper's speed."""
    return [obs[:, 27:28] - obs[:, 5:6], obs[:, 2:3], obs[:, 5:6], obs[:, 9:11], _norm(obs[:, 20:23])]


def distances_view(obs: Any) -> Any:
    """How far things are, not in which direction (n, 8): the gripper-to-object distance, the object-to-goal
    distance horizontally and its height part, the heights of gripper and object, the fingers, and the gripper's
    speed. A layout turned about the vertical axis looks the same, so a few demonstrations cover every placement.
    For `--train.imitation.disc-obs digail.envs.fetch:distances_view`."""
    import torch

    to_goal = obs[:, 25:28] - obs[:, 3:6]
    return torch.cat([_norm(obs[:, 6:9]), _norm(to_goal[:, :2]), *_distances_rest(obs)], -1)


def log_distances_view(obs: Any) -> Any:
    """The distances view with the gripper-to-object and object-to-goal distances on a log scale (log of metres plus
    1 cm), so that 2 cm against 10 cm from the goal weighs as much as 10 cm against 50: what decides success (within
    5 cm) is graded, not only the way there. For `--train.imitation.disc-obs digail.envs.fetch:log_distances_view`."""
    import torch

    to_goal = obs[:, 25:28] - obs[:, 3:6]
    return torch.cat([(_norm(obs[:, 6:9]) + 0.01).log(), (_norm(to_goal) + 0.01).log(), *_distances_rest(obs)], -1)


def flatten_fetch_obs(obs: dict[str, np.ndarray]) -> np.ndarray:
    """`concat(observation, desired_goal)` as float64 (layout in the module docstring)."""
    return np.concatenate([np.asarray(obs["observation"], dtype=np.float64),
                           np.asarray(obs["desired_goal"], dtype=np.float64)])


class FlatFetchPickAndPlace(gym.Env):
    """FetchPickAndPlace-v4 with flat `concat(observation, desired_goal)` observations and phase labels.

    It holds the original env rather than subclassing `gym.Wrapper`, so that `env.unwrapped` is this object
    and scripted experts can read the phase (`phase`) and the last observation (`last_obs`) through it.
    """

    metadata: dict[str, Any] = {"render_modes": ["human", "rgb_array", "depth_array"], "render_fps": 25}

    def __init__(self, render_mode: str | None = None, **kwargs: Any) -> None:
        try:
            import gymnasium_robotics
        except ImportError as exc:  # pragma: no cover - depends on the install
            from digail.errors import UserError

            raise UserError(f"{FETCH_ENV_ID} needs gymnasium-robotics; install it with "
                            "`pip install 'digail[robotics]'`.") from exc
        gym.register_envs(gymnasium_robotics)
        # The original's own wrappers (time limit, checker) are dropped; this env is registered with the limit
        self.fetch: Any = gym.make(INNER_ENV_ID, render_mode=render_mode, **kwargs).unwrapped  # MuJoCo env, untyped
        self.render_mode = render_mode
        self.metadata = {**self.metadata, **getattr(self.fetch, "metadata", {})}
        self.action_space = self.fetch.action_space
        self.observation_space = gym.spaces.Box(-np.inf, np.inf, shape=(OBS_DIM,), dtype=np.float64)
        self.phase = int(Phase.REACH)
        self.last_obs = np.zeros(OBS_DIM)
        self._geoms: tuple[int, ...] | None = None

    def reset(self, *, seed: int | None = None, options: dict[str, Any] | None = None
              ) -> tuple[np.ndarray, dict[str, Any]]:
        super().reset(seed=seed)
        obs, info = self.fetch.reset(seed=seed, options=options)
        self.last_obs = flatten_fetch_obs(obs)
        self.phase = next_phase(int(Phase.REACH), self.last_obs)
        return self.last_obs.copy(), {**info, "subtask": self.phase}

    def step(self, action: np.ndarray) -> tuple[np.ndarray, float, bool, bool, dict[str, Any]]:
        obs, reward, terminated, truncated, info = self.fetch.step(action)
        self.last_obs = flatten_fetch_obs(obs)
        self.phase = next_phase(self.phase, self.last_obs)
        info = {**info, "subtask": self.phase,
                **task_info(self.last_obs, self.fetch.height_offset, self._fingers_touch_object())}
        return self.last_obs.copy(), float(reward), bool(terminated), bool(truncated), info

    def _fingers_touch_object(self) -> bool:
        """Whether both finger geoms are in contact with the object in the current MuJoCo state."""
        import mujoco

        model, data = self.fetch.model, self.fetch.data
        if self._geoms is None:
            self._geoms = tuple(mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_GEOM, name) for name in
                                ("object0", "robot0:l_gripper_finger_link", "robot0:r_gripper_finger_link"))
        obj, *fingers = self._geoms
        touching = set()
        for contact in data.contact[:data.ncon]:
            pair = {int(contact.geom1), int(contact.geom2)}
            if obj in pair:
                touching |= pair
        return all(f in touching for f in fingers)

    def render(self) -> Any:
        return self.fetch.render()

    def close(self) -> None:
        self.fetch.close()


class RelativeFetchPickAndPlace(FlatFetchPickAndPlace):
    """`digail/FetchPickAndPlaceRelative-v4`: the same env observed in the relative view (24 numbers, the layout of
    `relative_view`): the object from the gripper, the goal from the object, the heights of gripper and object,
    then fingers, rotation and velocities as in the flat observation. No horizontal position is observed, and the
    actions move the gripper in world coordinates, so a policy here is the same wherever the object and the goal
    lie: what a few demonstrations show holds across the table. Dynamics, actions, rewards, infos and phase labels
    are the flat env's; `last_obs` stays the flat observation (the scripted expert reads it)."""

    def __init__(self, render_mode: str | None = None, **kwargs: Any) -> None:
        super().__init__(render_mode=render_mode, **kwargs)
        self.observation_space = gym.spaces.Box(-np.inf, np.inf, shape=(RELATIVE_DIM,), dtype=np.float64)

    def reset(self, *, seed: int | None = None, options: dict[str, Any] | None = None
              ) -> tuple[np.ndarray, dict[str, Any]]:
        flat, info = super().reset(seed=seed, options=options)
        return np.concatenate(_relative_parts(flat[None]), -1)[0], info

    def step(self, action: np.ndarray) -> tuple[np.ndarray, float, bool, bool, dict[str, Any]]:
        flat, reward, terminated, truncated, info = super().step(action)
        return np.concatenate(_relative_parts(flat[None]), -1)[0], reward, terminated, truncated, info
