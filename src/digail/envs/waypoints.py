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

Harder variants, each off by default: legs that are arcs around a centre (`centres`), joined so that the direction
of travel does not jump where one ends and the next begins; legs that weave towards their waypoint (`weave`: a
sideways sine of the distance still to go, so the sub-task's action is not linear in the position); a random
scale of the whole course per episode (`scale_noise`); observation dimensions that carry nothing
(`distractors`: random walks); and episodes that begin in a random sub-task (`random_first`).
"""

from __future__ import annotations

import math
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
        centres: continuous only: per leg of `order`, the centre of the arc the expert drives around to that
            waypoint, or None for a straight leg (`arc_course` builds arcs that join smoothly).
        turns: per leg with a centre, +1 to drive around it counter-clockwise, -1 clockwise.
        weave: continuous only: amplitude (in units of the leg's direction) of the expert's sideways weave.
        scale_noise: std of the log of a per-episode factor that scales the course (waypoints, centres, start).
        distractors: extra observation dimensions, each an independent Gaussian random walk (step std 0.1).
        random_first: each episode begins at a random leg of the cyclic `order`, from the waypoint before it, and
            drives once around (len(order) legs).
    """

    metadata: dict[str, Any] = {"render_modes": []}

    def __init__(self, waypoints: Sequence[Sequence[float]] = ((1.0, 0.0), (0.0, 0.0)),
                 order: Sequence[int] = (0, 1), start: Sequence[float] = (0.0, 0.0), speed: float = 0.05,
                 reach: float = 0.05, grid: bool = False, start_noise: float = 0.0, max_steps: int = 400,
                 centres: Sequence[Sequence[float] | None] | None = None, turns: Sequence[int] | None = None,
                 weave: float = 0.0, scale_noise: float = 0.0, distractors: int = 0,
                 random_first: bool = False) -> None:
        self.base_waypoints = np.asarray(waypoints, np.float64)
        self.base_order = [int(i) for i in order]
        self.base_start = np.asarray(start, np.float64)
        self.speed, self.reach, self.grid = float(speed), float(reach), bool(grid)
        self.start_noise, self.max_steps = float(start_noise), int(max_steps)
        n_legs = len(self.base_order)
        self.base_centres = [None if c is None else np.asarray(c, np.float64) for c in (centres or [None] * n_legs)]
        self.base_turns = [int(t) for t in (turns or [1] * n_legs)]
        if len(self.base_centres) != n_legs or len(self.base_turns) != n_legs:
            raise ValueError(f"centres and turns need one entry per leg of order ({n_legs}).")
        self.weave, self.scale_noise = float(weave), float(scale_noise)
        self.distractors, self.random_first = int(distractors), bool(random_first)
        self.waypoints, self.order, self.start = self.base_waypoints, self.base_order, self.base_start
        self.centres, self.turns = self.base_centres, self.base_turns
        self.noise_dims = np.zeros(self.distractors)
        hi = float(np.abs(self.waypoints).max() + np.abs(self.start).max() + 10)
        self.observation_space = spaces.Box(-hi * 4, hi * 4, (2 + self.distractors,), np.float32)
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

    @property
    def centre(self) -> np.ndarray | None:
        """the centre of the current leg's arc (None: a straight leg)"""
        return self.centres[min(self.leg, len(self.order) - 1)]

    @property
    def turn(self) -> int:
        """+1: the current arc runs counter-clockwise, -1: clockwise"""
        return self.turns[min(self.leg, len(self.order) - 1)]

    def _obs(self) -> np.ndarray:
        return np.r_[self.pos, self.noise_dims].astype(np.float32)

    def _reached(self) -> bool:
        if self.grid:
            return bool(np.all(self.pos == self.target))
        return bool(np.linalg.norm(self.pos - self.target) <= self.reach)

    def reset(self, *, seed: int | None = None, options: dict[str, Any] | None = None) -> tuple[np.ndarray, dict]:
        super().reset(seed=seed)
        scale = float(np.exp(self.scale_noise * self.np_random.standard_normal())) if self.scale_noise > 0 else 1.0
        self.waypoints, self.start = self.base_waypoints * scale, self.base_start * scale
        self.centres = [None if c is None else c * scale for c in self.base_centres]
        self.order, self.turns = self.base_order, self.base_turns
        if self.random_first:
            first = int(self.np_random.integers(len(self.base_order)))
            self.order = self.base_order[first:] + self.base_order[:first]
            self.centres = self.centres[first:] + self.centres[:first]
            self.turns = self.base_turns[first:] + self.base_turns[:first]
            self.start = self.waypoints[self.base_order[first - 1]]  # the waypoint before the first leg's
        self.noise_dims = self.np_random.standard_normal(self.distractors)
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
        self.noise_dims = self.noise_dims + 0.1 * self.np_random.standard_normal(self.distractors)
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
        gap = self.env.target - np.asarray(obs, np.float64)[:2]  # the position (distractors follow it)
        if self.env.grid:
            if self.rng.random() < self.noise:
                return int(self.rng.integers(4))
            axis = int(np.argmax(np.abs(gap)))
            return (0 if gap[0] > 0 else 2) if axis == 0 else (1 if gap[1] > 0 else 3)
        dist = float(np.linalg.norm(gap))
        centre = self.env.centre
        if centre is not None and dist > 2 * self.env.speed:
            direction = self._arc(np.asarray(obs, np.float64)[:2], centre)
        else:
            # full speed until the last step, then exactly onto the waypoint
            direction = gap / max(dist, 1e-9) * min(1.0, dist / self.env.speed)
            if self.env.weave > 0 and dist > 2 * self.env.speed:
                side = np.array([-gap[1], gap[0]]) / max(dist, 1e-9)
                direction = direction + self.env.weave * math.sin(2 * math.pi * dist / 0.5) * side
                direction = direction / np.linalg.norm(direction)
        act = direction + self.noise * self.rng.standard_normal(2)
        return np.clip(act, -1.0, 1.0).astype(np.float32)

    def _arc(self, pos: np.ndarray, centre: np.ndarray) -> np.ndarray:
        """Unit direction along the current arc: the tangent at `pos`, steered back onto the arc's radius (the
        target waypoint's distance from the centre)."""
        out = pos - centre
        r = max(float(np.linalg.norm(out)), 1e-9)
        radius = float(np.linalg.norm(self.env.target - centre))
        tangent = self.env.turn * np.array([-out[1], out[0]]) / r
        direction = tangent + 2.0 * (radius - r) / radius * out / r
        return direction / np.linalg.norm(direction)


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


def arc_course(start: Sequence[float], heading: float, legs: Sequence[tuple[float, float]]) -> dict[str, Any]:
    """`WaypointCourseEnv` arguments of a course of arcs joined smoothly: from `start`, heading `heading` (radians),
    each leg (radius, angle) turns through `angle` radians (positive: left, counter-clockwise) on a circle of
    `radius`. Each arc begins tangent to where the last one ended, so the direction of travel is continuous and
    only the curvature changes between sub-tasks."""
    pos, head = np.asarray(start, np.float64), float(heading)
    waypoints, centres, turns = [], [], []
    for radius, angle in legs:
        turn = 1 if angle > 0 else -1
        normal = turn * np.array([-math.sin(head), math.cos(head)])  # towards the centre
        centre = pos + radius * normal
        out = pos - centre
        rot = np.array([[math.cos(angle), -math.sin(angle)], [math.sin(angle), math.cos(angle)]])
        pos, head = centre + rot @ out, head + angle
        waypoints.append((round(float(pos[0]), 6), round(float(pos[1]), 6)))  # plain floats: Minari keeps them
        centres.append((round(float(centre[0]), 6), round(float(centre[1]), 6)))
        turns.append(turn)
    return dict(waypoints=tuple(waypoints), order=tuple(range(len(legs))), start=tuple(start), centres=tuple(centres),
                turns=tuple(turns))


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
    "curved": Course("3 sub-tasks: arcs around different centres joined smoothly (left, right, left); the direction "
                     "of travel never jumps, only the curvature changes; the course's scale varies per episode",
                     dict(arc_course((0.0, 0.0), 0.0, [(1.0, 1.6), (0.6, -2.4), (1.2, 1.8)]), speed=0.05,
                          start_noise=0.02, scale_noise=0.1), codes=3, episodes=20, noise=0.1),
    "weave": Course("3 sub-tasks whose policies are not linear in the state: each leg of a triangle weaves "
                    "sideways as a sine of the distance still to go",
                    dict(waypoints=((1.5, 0.0), (0.75, 1.3), (0.0, 0.0)), order=(0, 1, 2), start=(0.0, 0.0),
                         speed=0.05, start_noise=0.02, weave=0.8), codes=3, episodes=20, noise=0.1),
    "distractors": Course("4 sub-tasks (the square) observed with 8 extra dimensions of random walk that carry "
                          "nothing", dict(waypoints=((1.0, 0.0), (1.0, 1.0), (0.0, 1.0), (0.0, 0.0)),
                                          order=(0, 1, 2, 3), start=(0.0, 0.0), speed=0.05, start_noise=0.02,
                                          distractors=8), codes=4, episodes=15, noise=0.1),
    "random-first": Course("4 sub-tasks around a square on a grid, discrete actions, each episode starting in a "
                           "random one of them and going once around",
                           dict(waypoints=((8, 0), (8, 8), (0, 8), (0, 0)), order=(0, 1, 2, 3), start=(0, 0),
                                grid=True, start_noise=1, max_steps=200, random_first=True), codes=4, episodes=30,
                           noise=0.1),
    "many-short": Course("8 short sub-tasks (about 7 steps each) around an octagon, each leg turning 45 degrees",
                         dict(waypoints=tuple((round(sum(0.35 * math.cos(math.pi / 4 * j) for j in range(i + 1)), 6),
                                               round(sum(0.35 * math.sin(math.pi / 4 * j) for j in range(i + 1)), 6))
                                              for i in range(8)),
                              order=tuple(range(8)), start=(0.0, 0.0), speed=0.05, start_noise=0.01),
                         codes=8, episodes=30, noise=0.1),
}
"""the synthetic tasks of `benchmarks/segmentation.py` (the shipped data sets are added there)"""
