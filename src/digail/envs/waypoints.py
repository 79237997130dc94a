"""Waypoint courses: small synthetic worlds for the segmentation benchmark (`benchmarks/segmentation.py`).

An agent visits waypoints in a fixed order; the sub-task is the waypoint it is heading for, reported as the oracle
label in every step's info under "subtask" (and never in the observation, which is the agent's position alone).
Visiting the same waypoint twice is the same sub-task again, so a course such as A -> B -> A -> B repeats its
sub-tasks, and on a shuttle between two points the position does not reveal the sub-task (only the direction of
travel, i.e. the history or the code, does). The episode terminates when the last waypoint is reached.

Two kinds of world:

- continuous (`grid=False`): positions in the plane, actions in [-1, 1]^2 scaled by `speed`;
- grid (`grid=True`): integer cells, four discrete actions (right, up, left, down).

`WaypointExpert` is the scripted expert: it heads straight for the current waypoint (continuous: unit direction,
plus Gaussian noise; grid: along the longer axis first, plus random actions with probability `noise`).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import gymnasium as gym
import numpy as np
from gymnasium import spaces

SUBTASK_INFO_KEY = "subtask"
"""info key of the oracle label (`digail.data.trajectory.SUBTASK_KEY`, not imported: envs sit below data)"""

GRID_MOVES = np.array([[1, 0], [0, 1], [-1, 0], [0, -1]], np.int64)
"""grid actions: right, up, left, down"""


class WaypointCourseEnv(gym.Env[np.ndarray, Any]):
    """Visit `waypoints[order[0]]`, then `waypoints[order[1]]`, ...; the label is the index of the current target.

    Args:
        waypoints: (n, 2) positions (grid cells for `grid`).
        order: the waypoint indices to visit, in order; the episode starts at `start`.
        start: start position (continuous: jittered by `start_noise` each reset).
        speed: continuous step length for an action of norm 1.
        reach: continuous distance at which a waypoint counts as reached.
        grid: integer cells and four discrete actions instead of the plane.
        start_noise: std of the continuous start position's jitter (uniform over +-`start_noise` cells on a grid).
        max_steps: truncation limit.
    """

    metadata: dict[str, Any] = {"render_modes": []}

    def __init__(self, waypoints: Sequence[Sequence[float]] = ((1.0, 0.0), (0.0, 0.0)),
                 order: Sequence[int] = (0, 1), start: Sequence[float] = (0.0, 0.0), speed: float = 0.05,
                 reach: float = 0.05, grid: bool = False, start_noise: float = 0.0, max_steps: int = 400) -> None:
        self.waypoints = np.asarray(waypoints, np.float64)
        self.order = [int(i) for i in order]
        self.start = np.asarray(start, np.float64)
        self.speed, self.reach, self.grid = float(speed), float(reach), bool(grid)
        self.start_noise, self.max_steps = float(start_noise), int(max_steps)
        hi = float(np.abs(self.waypoints).max() + np.abs(self.start).max() + 10)
        self.observation_space = spaces.Box(-hi, hi, (2,), np.float32)
        self.action_space: spaces.Space[Any] = (spaces.Discrete(4) if grid
                                                else spaces.Box(-1.0, 1.0, (2,), np.float32))
        self.pos = self.start.copy()
        self.leg = 0
        self.steps = 0

    @property
    def target(self) -> np.ndarray:
        """the waypoint the agent heads for now"""
        return self.waypoints[self.order[min(self.leg, len(self.order) - 1)]]

    @property
    def label(self) -> int:
        """oracle sub-task: the index of the current target waypoint"""
        return self.order[min(self.leg, len(self.order) - 1)]

    def _obs(self) -> np.ndarray:
        return self.pos.astype(np.float32)

    def _reached(self) -> bool:
        if self.grid:
            return bool(np.all(self.pos == self.target))
        return bool(np.linalg.norm(self.pos - self.target) <= self.reach)

    def reset(self, *, seed: int | None = None, options: dict[str, Any] | None = None) -> tuple[np.ndarray, dict]:
        super().reset(seed=seed)
        self.pos, self.leg, self.steps = self.start.copy(), 0, 0
        if self.start_noise > 0:
            if self.grid:
                k = int(self.start_noise)
                self.pos = self.pos + self.np_random.integers(-k, k + 1, size=2)
            else:
                self.pos = self.pos + self.start_noise * self.np_random.standard_normal(2)
        return self._obs(), {SUBTASK_INFO_KEY: self.label}

    def step(self, action: Any) -> tuple[np.ndarray, float, bool, bool, dict]:
        if self.grid:
            self.pos = self.pos + GRID_MOVES[int(action)]
        else:
            self.pos = self.pos + self.speed * np.clip(np.asarray(action, np.float64), -1.0, 1.0)
        self.steps += 1
        while self.leg < len(self.order) and self._reached():
            self.leg += 1
        done = self.leg >= len(self.order)
        reward = -float(np.linalg.norm(self.pos - self.target))
        truncated = not done and self.steps >= self.max_steps
        return self._obs(), reward, done, truncated, {SUBTASK_INFO_KEY: self.label}


class WaypointExpert:
    """Scripted expert of `WaypointCourseEnv`: straight for the current waypoint, with noise.

    Args:
        env: the (unwrapped) course env whose target it reads.
        noise: continuous: std of Gaussian noise added to the unit direction; grid: probability of a random action.
        seed: seeds the noise.
    """

    def __init__(self, env: WaypointCourseEnv, noise: float = 0.0, seed: int = 0) -> None:
        self.env, self.noise = env, float(noise)
        self.rng = np.random.default_rng(seed)

    def __call__(self, obs: np.ndarray) -> Any:
        gap = self.env.target - np.asarray(obs, np.float64)
        if self.env.grid:
            if self.rng.random() < self.noise:
                return int(self.rng.integers(4))
            axis = int(np.argmax(np.abs(gap)))
            return (0 if gap[0] > 0 else 2) if axis == 0 else (1 if gap[1] > 0 else 3)
        dist = float(np.linalg.norm(gap))
        # full speed until the last step, then exactly onto the waypoint
        direction = gap / max(dist, 1e-9) * min(1.0, dist / self.env.speed)
        act = direction + self.noise * self.rng.standard_normal(2)
        return np.clip(act, -1.0, 1.0).astype(np.float32)


COURSE_ENV_ID = "digail/WaypointCourse-v0"
"""Gymnasium id of `WaypointCourseEnv` (its kwargs pick the course)"""


@dataclass(frozen=True)
class Course:
    """One task of the segmentation benchmark: a course, its expert's noise and how many episodes to record."""

    description: str
    """what the task tests"""
    kwargs: dict[str, Any]
    """`WaypointCourseEnv` arguments"""
    codes: int
    """true number of sub-tasks K (distinct waypoints in the order)"""
    episodes: int
    """episodes to record"""
    noise: float = 0.0
    """`WaypointExpert` noise"""


def _shuttle(n: int) -> dict[str, Any]:
    # from A = (0, 0) to B = (1, 0) and back, n legs: the same positions are crossed in both directions
    return dict(waypoints=((1.0, 0.0), (0.0, 0.0)), order=tuple(i % 2 for i in range(n)), start=(0.0, 0.0),
                speed=0.05, start_noise=0.02)


COURSES: dict[str, Course] = {
    "shuttle": Course("2 sub-tasks, A -> B -> A: the position does not reveal the sub-task, only the direction "
                      "of travel", _shuttle(2), codes=2, episodes=20, noise=0.1),
    "shuttle-repeat": Course("2 sub-tasks repeated within an episode (A -> B -> A -> B -> A), 4 switches",
                             _shuttle(4), codes=2, episodes=15, noise=0.1),
    "square": Course("4 sub-tasks: the corners of a square in turn, 3 switches",
                     dict(waypoints=((1.0, 0.0), (1.0, 1.0), (0.0, 1.0), (0.0, 0.0)), order=(0, 1, 2, 3),
                          start=(0.0, 0.0), speed=0.05, start_noise=0.02), codes=4, episodes=15, noise=0.1),
    # (a first version went +x, +y, +x: its first and last sub-tasks differ only in where they happen, which grid-six
    # already tests; here only the lengths are unusual)
    "unequal": Course("3 sub-tasks of very unequal length (about 4, 40 and 10 steps)",
                      dict(waypoints=((0.2, 0.0), (0.2, 2.0), (-0.3, 2.0)), order=(0, 1, 2), start=(0.0, 0.0),
                           speed=0.05, start_noise=0.01), codes=3, episodes=20, noise=0.1),
    "noisy": Course("3 sub-tasks, a triangle driven by a noisy expert (noise std 0.5 on a unit direction)",
                    dict(waypoints=((1.0, 0.0), (0.5, 0.8), (0.0, 0.0)), order=(0, 1, 2), start=(0.0, 0.0),
                         speed=0.05, start_noise=0.02), codes=3, episodes=20, noise=0.5),
    "grid-six": Course("6 sub-tasks on a 12 x 12 grid, discrete actions, 10% random actions",
                       dict(waypoints=((6, 0), (6, 6), (0, 6), (0, 12), (12, 12), (12, 0)), order=(0, 1, 2, 3, 4, 5),
                            start=(0, 0), grid=True, start_noise=1, max_steps=200), codes=6, episodes=20,
                       noise=0.1),
    "grid-large": Course("3 sub-tasks on a grid, discrete actions, 600 episodes (about 20 000 steps): the large "
                         "data set", dict(waypoints=((10, 0), (10, 10), (0, 0)), order=(0, 1, 2), start=(0, 0),
                                          grid=True, start_noise=1, max_steps=200), codes=3, episodes=600,
                         noise=0.05),
}
"""the synthetic tasks of `benchmarks/segmentation.py` (the shipped data sets are added there)"""
