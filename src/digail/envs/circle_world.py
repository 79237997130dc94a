"""Circle-World: draw a circle clockwise, then retrace it counter-clockwise (paper Sec. 5.2).

Geometry. Every episode draws a radius `r ~ U[r_min, r_max]` and uses the circle through the origin with
centre `(0, r)`: `x^2 + (y - r)^2 = r^2`. Every point with `y > 0` lies on exactly one such circle, the one
with `r = (x^2 + y^2) / (2 y)`, so a policy that sees only `(x, y)` can still tell which circle it is on;
what it cannot tell from the position alone is the direction, which is what makes the task multi-modal.

Reference path (what the scripted expert follows). With `n = steps_per_circle` (60) and `y` pointing up, the
reference point of step `k` is `(0, r) + r (cos theta_k, sin theta_k)` with
`theta_k = -pi/2 - 2 pi k / n` for `k <= n` (clockwise, starting leftwards from the origin) and
`theta_k = -pi/2 - 2 pi (2n - k) / n` for `n <= k <= 2n` (the same points back, counter-clockwise).
Consecutive reference points are one chord `2 r sin(pi / n)` apart, exactly the env's step length.

Scoring. `circle_scores` judges a drawn path of `2n + 1` positions (start included) half by half: the sign of
the shoelace signed area gives the drawing direction (positive = counter-clockwise), an algebraic
least-squares circle fit gives the radius, and the gap between a half's first and last point its closure.
"""

from __future__ import annotations

import math
from typing import Any

import gymnasium as gym
import numpy as np
from gymnasium import spaces

from digail.errors import UserError

STEPS_PER_CIRCLE = 60
"""Default number of steps to draw one circle (an episode draws two)."""

MIN_AREA = 0.5
"""Share of the target circle's area (pi r^2) a half must enclose, with the right sign, to count as drawn."""

SCORE_KEYS = (
    "order_correct",
    "order_reversed",
    "radius_error",
    "closure_error",
    "area_first",
    "area_second",
)
"""Keys `circle_scores` returns; the env adds them to the info of an episode's final step."""


def reference_point(radius: float, step: int, steps_per_circle: int = STEPS_PER_CIRCLE) -> np.ndarray:
    """Point of the reference path after `step` steps (see the module docstring), float64 of shape (2,).

    Steps beyond `2 * steps_per_circle` stay at the origin, where the reference path ends.
    """
    k = min(max(int(step), 0), 2 * steps_per_circle)
    turns = k if k <= steps_per_circle else 2 * steps_per_circle - k
    theta = -0.5 * math.pi - 2.0 * math.pi * turns / steps_per_circle
    return np.array([radius * math.cos(theta), radius + radius * math.sin(theta)])


def reversed_reference_point(radius: float, step: int, steps_per_circle: int = STEPS_PER_CIRCLE) -> np.ndarray:
    """Point after `step` steps of the order never demonstrated: the same circle counter-clockwise first (the
    reference path's second half, from the origin), then clockwise (its first half), float64 of shape (2,).

    What `digail.experts.scripted.circle_reversed_expert` follows; the reversed composition is scored against it.
    """
    n = int(steps_per_circle)
    k = min(max(int(step), 0), 2 * n)
    return reference_point(radius, n - k if k <= n else k - n, n)


def _signed_area(points: np.ndarray) -> float:
    """Shoelace signed area of the closed polygon through `points` (positive = counter-clockwise)."""
    x, y = points[:, 0], points[:, 1]
    return 0.5 * float(np.sum(x * np.roll(y, -1) - np.roll(x, -1) * y))


def fit_circle_radius(points: np.ndarray) -> float:
    """Radius of the algebraic least-squares (Kasa) circle fit of 2-D `points`.

    Solves `x^2 + y^2 + D x + E y + F = 0` in the least-squares sense (points centred first, for conditioning)
    and returns `sqrt((D^2 + E^2) / 4 - F)`. Points that are all equal give 0; collinear points (no finite
    circle) give `inf`.
    """
    centred = np.asarray(points, dtype=np.float64) - np.mean(points, axis=0)
    scale = float(np.max(np.abs(centred)))
    if scale < 1e-12:
        return 0.0
    u = centred / scale
    design = np.column_stack([u, np.ones(len(u))])
    target = -np.sum(u**2, axis=1)
    (d, e, f), _, rank, _ = np.linalg.lstsq(design, target, rcond=None)
    radius_sq = 0.25 * (d * d + e * e) - f
    if rank < 3 or not np.isfinite(radius_sq) or radius_sq <= 0:
        return math.inf
    return scale * math.sqrt(radius_sq)


def circle_scores(
    positions: np.ndarray, radius: float, steps_per_circle: int = STEPS_PER_CIRCLE
) -> dict[str, Any]:
    """Score a Circle-World drawing: direction of each half, radius and closure errors.

    The first half is `positions[: n + 1]` and the second `positions[n:]` (they share the middle point), with
    `n = steps_per_circle`. Pure function: works on any path of this length, e.g. one drawn under a composed
    code schedule.

    Args:
        positions: (2 n + 1, 2) array of visited positions, start included.
        radius: the episode's target radius `r` (> 0).
        steps_per_circle: `n`, steps per half.

    Returns:
        `order_correct` (bool): first half clockwise and second counter-clockwise, each half enclosing at least
        `MIN_AREA` of the target circle's area with the right sign (a scribble near the origin does not count);
        `order_reversed` (bool): first half counter-clockwise and second clockwise, by the same rule;
        `radius_error` (float): mean over halves of `|fitted radius - r| / r` (`inf` if a half is a straight
        line);
        `closure_error` (float): mean over halves of `|first point - last point| / r`;
        `area_first`, `area_second` (float): each half's signed area divided by `pi r^2` (the expert scores
        about -1 and +1; values near 0 mean the half hardly encloses anything, whatever its sign).
    """
    n = int(steps_per_circle)
    points = np.asarray(positions, dtype=np.float64)
    if n < 2 or points.shape != (2 * n + 1, 2):
        raise ValueError(f"circle_scores expects positions of shape ({2 * n + 1}, 2), got {points.shape}.")
    if not (math.isfinite(radius) and radius > 0):
        raise ValueError(f"circle_scores expects a positive finite radius, got {radius}.")
    halves = (points[: n + 1], points[n:])
    areas = [_signed_area(half) / (math.pi * radius**2) for half in halves]
    radius_errors = [abs(fit_circle_radius(half) - radius) / radius for half in halves]
    closures = [float(np.linalg.norm(half[-1] - half[0])) / radius for half in halves]
    return {
        "order_correct": bool(areas[0] < -MIN_AREA and areas[1] > MIN_AREA),
        "order_reversed": bool(areas[0] > MIN_AREA and areas[1] < -MIN_AREA),
        "radius_error": float(np.mean(radius_errors)),
        "closure_error": float(np.mean(closures)),
        "area_first": float(areas[0]),
        "area_second": float(areas[1]),
    }


class CircleWorldEnv(gym.Env[np.ndarray, np.ndarray]):
    """A point in the plane drawing one circle clockwise, then the same circle counter-clockwise.

    - **Reset**: position `(0, 0)`; radius `r ~ U[r_min, r_max]` (or `options={"radius": r}`).
    - **Observation**: the position `(x, y)`, float32, in a Box whose bounds are the farthest one episode can
      reach (`2 n` steps of the longest chord, about 18.8 with the defaults).
    - **Action**: `Box(-1, 1, (2,), float32)`, a direction; the env normalises it to a unit vector (a zero
      vector does not move) and moves by the episode's chord length `2 r sin(pi / steps_per_circle)`.
    - **Reward**: minus the distance between the new position and the reference point of that step (see
      `reference_point`); the scripted expert scores about 0. Returns are only a secondary score here.
    - **Episode end**: truncation after `2 * steps_per_circle` steps (120), by the env itself and by the
      registered time limit; never terminates.
    - **info**: `subtask` (0 while in the clockwise half, i.e. after 0..n-1 steps; 1 after n steps or more,
      so the label of a state is the direction of the action taken from it) and `radius` (the episode's r),
      at reset and every step; on the final step also the `circle_scores` of the visited positions
      (`SCORE_KEYS`).

    Args:
        render_mode: None or "rgb_array".
        r_min: smallest radius.
        r_max: largest radius.
        steps_per_circle: steps per circle `n`; register with `max_episode_steps=2 n` when changing it.

    Attributes:
        radius: this episode's radius.
        t: steps taken in this episode.
        position: current position (float64 internally; observations are float32).
    """

    metadata = {"render_modes": ["rgb_array"], "render_fps": 30}

    IMAGE_SIZE = 256
    """Side of rendered images in pixels."""

    def __init__(
        self,
        render_mode: str | None = None,
        r_min: float = 0.5,
        r_max: float = 1.5,
        steps_per_circle: int = STEPS_PER_CIRCLE,
    ) -> None:
        if render_mode is not None and render_mode not in self.metadata["render_modes"]:
            raise UserError(
                f"Unsupported render_mode {render_mode!r} for CircleWorld; use 'rgb_array' or None."
            )
        if not (math.isfinite(r_min) and math.isfinite(r_max) and 0 < r_min <= r_max):
            raise UserError(f"CircleWorld needs 0 < r_min <= r_max, got r_min={r_min}, r_max={r_max}.")
        if int(steps_per_circle) < 3:
            raise UserError(f"CircleWorld needs steps_per_circle >= 3, got {steps_per_circle}.")
        self.render_mode = render_mode
        self.r_min, self.r_max = float(r_min), float(r_max)
        self.steps_per_circle = int(steps_per_circle)
        # No position can be farther from the origin than a whole episode of the longest steps (plus a margin
        # for rounding).
        reach = (
            2 * self.steps_per_circle * 2.0 * self.r_max * math.sin(math.pi / self.steps_per_circle) * 1.0001
        )
        self.observation_space = spaces.Box(-reach, reach, shape=(2,), dtype=np.float32)
        self.action_space = spaces.Box(-1.0, 1.0, shape=(2,), dtype=np.float32)
        self.radius = self.r_min
        self.t = 0
        self.position = np.zeros(2)
        self._path: list[np.ndarray] = [self.position.copy()]

    @staticmethod
    def canonical_action(acts: Any) -> Any:
        """What the env executes for a batch of actions: unit directions (torch or NumPy, last axis 2).

        Only the direction of an action matters here, so imitation compares directions, not raw vectors.
        """
        norm = (acts * acts).sum(-1, keepdims=True) ** 0.5 if isinstance(acts, np.ndarray) else \
            acts.norm(dim=-1, keepdim=True)
        return acts / (norm + 1e-8)

    @property
    def episode_steps(self) -> int:
        """Steps in a full episode: two circles."""
        return 2 * self.steps_per_circle

    @property
    def step_length(self) -> float:
        """Distance moved per step: the chord between consecutive reference points."""
        return 2.0 * self.radius * math.sin(math.pi / self.steps_per_circle)

    @property
    def positions(self) -> np.ndarray:
        """Positions visited so far in this episode, start included, shape (t + 1, 2), float64."""
        return np.array(self._path)

    def _obs(self) -> np.ndarray:
        return self.position.astype(np.float32)

    def _info(self) -> dict[str, Any]:
        return {"subtask": int(self.t >= self.steps_per_circle), "radius": self.radius}

    def reset(
        self, *, seed: int | None = None, options: dict[str, Any] | None = None
    ) -> tuple[np.ndarray, dict[str, Any]]:
        super().reset(seed=seed)
        options = options or {}
        if "radius" in options:
            radius = float(options["radius"])
            if not (math.isfinite(radius) and radius > 0):
                raise UserError(f"options['radius'] must be a positive number, got {options['radius']!r}.")
        else:
            radius = float(self.np_random.uniform(self.r_min, self.r_max))
        self.radius = radius
        self.t = 0
        self.position = np.zeros(2)
        self._path = [self.position.copy()]
        return self._obs(), self._info()

    def step(self, action: Any) -> tuple[np.ndarray, float, bool, bool, dict[str, Any]]:
        direction = np.asarray(action, dtype=np.float64).reshape(-1)
        if direction.shape != (2,) or not np.all(np.isfinite(direction)):
            raise ValueError(f"CircleWorld action must be 2 finite numbers, got {action!r}.")
        norm = float(np.linalg.norm(direction))
        if norm > 1e-12:
            self.position = self.position + self.step_length * direction / norm
        self.t += 1
        self._path.append(self.position.copy())
        reference = reference_point(self.radius, self.t, self.steps_per_circle)
        reward = -float(np.linalg.norm(self.position - reference))
        truncated = self.t >= self.episode_steps
        info = self._info()
        if self.t == self.episode_steps:
            info.update(circle_scores(self.positions, self.radius, self.steps_per_circle))
        return self._obs(), reward, False, truncated, info

    def _to_pixels(self, points: np.ndarray) -> np.ndarray:
        """World `(x, y)` to image `(row, col)`, float; the view is a square around all circles."""
        span = 2.5 * self.r_max
        left, top = -0.5 * span, self.r_max + 0.5 * span
        scale = (self.IMAGE_SIZE - 1) / span
        return np.column_stack([(top - points[:, 1]) * scale, (points[:, 0] - left) * scale])

    def _draw_polyline(self, image: np.ndarray, points: np.ndarray, rgb: tuple[int, int, int]) -> None:
        pixels = self._to_pixels(points)
        for start, end in zip(pixels[:-1], pixels[1:], strict=True):
            count = max(2, int(np.ceil(np.abs(end - start).max())) + 1)
            samples = np.linspace(start, end, count)
            self._paint(image, samples, rgb, half_width=1)

    def _paint(
        self, image: np.ndarray, pixels: np.ndarray, rgb: tuple[int, int, int], half_width: int
    ) -> None:
        base = np.rint(pixels).astype(np.int64)
        for dr in range(-half_width, half_width + 1):
            for dc in range(-half_width, half_width + 1):
                rc = base + (dr, dc)
                keep = np.all((rc >= 0) & (rc < self.IMAGE_SIZE), axis=1)
                image[rc[keep, 0], rc[keep, 1]] = rgb

    def render(self) -> np.ndarray | None:  # type: ignore[override]
        """An RGB image (uint8, 256 x 256 x 3): the reference circle in grey, the clockwise part of the path
        in blue, the counter-clockwise part in green, the current position in red."""
        if self.render_mode != "rgb_array":
            return None
        image = np.full((self.IMAGE_SIZE, self.IMAGE_SIZE, 3), 255, dtype=np.uint8)
        angles = np.linspace(0.0, 2.0 * math.pi, 361)
        circle = np.column_stack([self.radius * np.cos(angles), self.radius * (1.0 + np.sin(angles))])
        self._paint(image, self._to_pixels(circle), (200, 200, 200), half_width=0)
        path = self.positions
        n = self.steps_per_circle
        self._draw_polyline(image, path[: n + 1], (40, 90, 220))
        if len(path) > n + 1:
            self._draw_polyline(image, path[n:], (30, 160, 60))
        self._paint(image, self._to_pixels(path[-1:]), (220, 30, 30), half_width=3)
        return image


class CircleWorldVecEnv:
    """N Circle-World envs stepped together as arrays: the training rollouts' `sync` backend for this env.

    Follows `digail.envs.vector.VectorEnv` (same-step autoreset, `final` observations and infos of the envs that
    ended) and gives the numbers of N wrapped `CircleWorldEnv`s in `digail.envs.vector.VecEnv` bit for bit
    (tests/test_vector.py): every env keeps its own Gymnasium RNG for its radius, each step is the env's float64
    arithmetic on (N, 2) arrays, and the reference points are tabulated with `math.cos`/`math.sin` as in
    `reference_point`. Why: a Circle-World step is a few microseconds of arithmetic under tens of microseconds of
    per-env Python (wrappers, checks, info dicts), and a training iteration takes 512 of them.

    Args:
        env_id: the registered id (its time limit and keyword arguments apply, e.g. `max_episode_steps`).
        num_envs: N.
        **kwargs: passed to `gym.make` (and so to `CircleWorldEnv`).
    """

    def __init__(self, env_id: str, num_envs: int, **kwargs: Any) -> None:
        # made through the registry's entry, which names this class: the id is registered by then
        self._probe = gym.make(env_id, **kwargs)
        env = self._probe.unwrapped
        if not isinstance(env, CircleWorldEnv):
            raise UserError(f"CircleWorldVecEnv steps Circle-World only, not {env_id!r}.")
        spec = self._probe.spec
        limit = spec.max_episode_steps if spec is not None and spec.max_episode_steps is not None else None
        self.num_envs = num_envs
        self.single_action_space = self._probe.action_space
        self.r_min, self.r_max, self.n = env.r_min, env.r_max, env.steps_per_circle
        self.limit = min(2 * self.n, limit) if limit is not None else 2 * self.n
        self._sin_step = math.sin(math.pi / self.n)
        turns = [k if k <= self.n else 2 * self.n - k for k in range(2 * self.n + 1)]
        thetas = [-0.5 * math.pi - 2.0 * math.pi * k / self.n for k in turns]
        self._cos = np.array([math.cos(th) for th in thetas])
        self._sin = np.array([math.sin(th) for th in thetas])
        self._rngs: list[np.random.Generator | None] = [None] * num_envs
        self.radius = np.full(num_envs, self.r_min)
        self.t = np.zeros(num_envs, dtype=np.int64)
        self.position = np.zeros((num_envs, 2))
        self._path = np.zeros((num_envs, self.limit + 1, 2))

    @property
    def probe(self) -> gym.Env:
        return self._probe

    def _reset_one(self, i: int, seed: int | None) -> dict[str, Any]:
        from gymnasium.utils import seeding

        if seed is not None or self._rngs[i] is None:  # gym.Env.reset(seed=...) and its lazy unseeded RNG
            self._rngs[i], _ = seeding.np_random(seed)
        rng = self._rngs[i]
        assert rng is not None
        self.radius[i] = float(rng.uniform(self.r_min, self.r_max))
        self.t[i] = 0
        self.position[i] = 0.0
        self._path[i, 0] = 0.0
        return {"subtask": 0, "radius": float(self.radius[i])}

    def reset(self, seeds: Any) -> tuple[np.ndarray, list[dict[str, Any]]]:
        infos = [self._reset_one(i, s) for i, s in enumerate(seeds)]
        return self.position.astype(np.float32), infos

    def step(self, actions: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray,
                                                 list[dict[str, Any]], dict[int, tuple[np.ndarray, dict[str, Any]]]]:
        direction = np.asarray(actions, dtype=np.float64).reshape(self.num_envs, -1)
        if direction.shape[1] != 2 or not np.all(np.isfinite(direction)):
            raise ValueError(f"CircleWorld actions must be 2 finite numbers per env, got {actions!r}.")
        # np.linalg.norm of a 2-vector is this sum of squares' square root, bit for bit
        norm = np.sqrt(direction[:, 0] * direction[:, 0] + direction[:, 1] * direction[:, 1])
        moves = norm > 1e-12
        step_length = 2.0 * self.radius * self._sin_step
        moved = self.position + step_length[:, None] * direction / np.where(moves, norm, 1.0)[:, None]
        self.position = np.where(moves[:, None], moved, self.position)
        self.t += 1
        t = self.t
        rows = np.arange(self.num_envs)
        self._path[rows, t] = self.position
        k = np.minimum(t, 2 * self.n)
        reference = np.stack([self.radius * self._cos[k], self.radius + self.radius * self._sin[k]], 1)
        gap = self.position - reference
        rews = (-np.sqrt(gap[:, 0] * gap[:, 0] + gap[:, 1] * gap[:, 1])).astype(np.float32)
        truncs = t >= self.limit
        obs = self.position.astype(np.float32)
        infos = [{"subtask": int(t[i] >= self.n), "radius": float(self.radius[i])} for i in range(self.num_envs)]
        final: dict[int, tuple[np.ndarray, dict[str, Any]]] = {}
        for i in np.flatnonzero(truncs):
            info = infos[i]
            if t[i] == 2 * self.n:
                info.update(circle_scores(self._path[i, : t[i] + 1], float(self.radius[i]), self.n))
            final[int(i)] = (obs[i].copy(), info)
            infos[i] = self._reset_one(int(i), None)
            obs[i] = 0.0
        return obs, rews, np.zeros(self.num_envs, dtype=bool), truncs, infos, final

    def close(self) -> None:
        self._probe.close()
