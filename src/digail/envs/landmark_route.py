"""Landmark route: a point visits four landmarks in a given order, one leg per sub-task (a task beyond the paper).

Four landmarks stand near the corners of a square, labelled by corner: 0 north-east, 1 north-west, 2 south-west,
3 south-east (`LANDMARKS`, each moved by up to `JITTER` per coordinate every episode). The point starts near the
centre and drives to the landmarks of `order` in turn; leg `i` is "go to landmark `order[i]`" and its oracle label
is that landmark's number, so a sub-task is the same behaviour (head for one landmark) wherever it falls in the
route. The default order, the one the shipped demonstrations show, is `DEMO_ORDER` = (0, 2, 1, 3): north-east,
across the centre to south-west, up to north-west, across the centre again to south-east, about 195 steps (173-219).

Why this layout. The second leg leaves the first landmark back along the line the first leg came in on, and the
two diagonal legs cross near the centre, so the same positions are driven in different directions at different
times of an episode: a flat (memoryless) policy cannot be right on both, while a macro-policy that remembers its
code can (the label changes only when the point reaches the current target, so it is decided by the state and
the previous label). The touch sensors make that decision one feature: a leg ends where the sensor of its landmark
comes on. With positions alone the macro-policy must learn a distance threshold from about one switching state per
leg, and with the defaults it missed 5-30 % of the switches (segmentation accuracy 0.73-0.95 over the variants
tried, 1.00 with the sensors: docs/experiments/2026-12-05-landmark-route.md). Straight legs between corners never
pass within `REACH` of a third landmark, so any order can be driven without touching a landmark out of turn, and a
new order (`order=(3, 2, 1, 0)`, say) is a task the demonstrations never showed that the scripted expert still
solves (`digail.experts.scripted.route_expert`).

- **Observation** (float32, 14): the point's position `(x, y)`, the four landmarks' positions in label order (8),
  and a touch sensor per landmark (4: 1.0 while the point is within `REACH` of it, else 0.0).
- **Action**: `Box(-1, 1, (2,))`, clipped to the box and then to the unit disc; the point moves by `SPEED` times it.
- **Reward** (cost convention): minus the distance from the new position to the target of the leg being driven.
- **Legs**: a leg is done when the point comes within `REACH` of its landmark; the next leg starts there. Coming
  within `REACH` of any other landmark (except the one just left) is a wrong visit.
- **Episode end**: terminates when the last leg is done; truncated by the registered time limit (`MAX_EPISODE_STEPS`,
  100 steps a leg for four legs; pass `max_episode_steps` to `make_env` for longer orders).
- **info** at reset and every step: `subtask` (the landmark the point is heading for), `legs_done` (legs done so
  far), `leg_done` (1 at the step a leg is done), `wrong_visit` (1 at a step that enters a landmark out of turn),
  `is_success` (every leg done, in order, with no wrong visit).

`order` can be given as a sequence of landmark numbers or as text such as "2,0,1"; consecutive legs must go to
different landmarks.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import gymnasium as gym
import numpy as np
from gymnasium import spaces

from digail.errors import UserError

ROUTE_ENV_ID = "digail/LandmarkRoute-v0"
LANDMARKS: tuple[tuple[float, float], ...] = ((1.2, 1.2), (-1.2, 1.2), (-1.2, -1.2), (1.2, -1.2))
"""nominal landmark positions by label: 0 north-east, 1 north-west, 2 south-west, 3 south-east"""
LANDMARK_NAMES = ("north-east", "north-west", "south-west", "south-east")
"""what each label (landmark) is called"""
DEMO_ORDER = (0, 2, 1, 3)
"""the route of the default task and the shipped demonstrations"""
JITTER = 0.2
"""each landmark coordinate moves by U[-JITTER, JITTER] per episode"""
START_BOX = 0.2
"""the start position is U[-START_BOX, START_BOX]^2"""
SPEED = 0.05
"""distance moved by an action of norm 1"""
REACH = 0.2
"""a landmark is reached within this distance"""
STEPS_PER_LEG = 100
"""time allowed per leg (the expert needs at most about 75)"""
MAX_EPISODE_STEPS = STEPS_PER_LEG * len(DEMO_ORDER)
"""registered time limit"""
OBS_DIM = 2 + 3 * len(LANDMARKS)


def parse_order(order: str | Sequence[int]) -> tuple[int, ...]:
    """A route as a tuple of landmark numbers, from a sequence or text such as "2,0,1".

    Raises:
        UserError: empty, not numbers, a number outside 0-3, or the same landmark twice in a row.
    """
    if isinstance(order, str):
        try:
            legs = tuple(int(part) for part in order.replace(" ", "").split(",") if part)
        except ValueError:
            raise UserError(f"route order {order!r} is not comma-separated landmark numbers; write e.g. "
                            "'2,0,1'.") from None
    else:
        legs = tuple(int(leg) for leg in order)
    n = len(LANDMARKS)
    if not legs:
        raise UserError(f"route order {order!r} has no legs; give at least one landmark number (0-{n - 1}).")
    if any(not 0 <= leg < n for leg in legs):
        raise UserError(f"route order {order!r} names a landmark outside 0-{n - 1}; use the labels 0 north-east, "
                        "1 north-west, 2 south-west, 3 south-east.")
    if any(a == b for a, b in zip(legs[:-1], legs[1:], strict=True)):
        raise UserError(f"route order {order!r} goes to the same landmark twice in a row; drop the repeat.")
    return legs


def relative_view(obs: Any) -> Any:
    """What a discriminator sees of observations (n, 14) under `--train.imitation.disc-obs relative`: each landmark
    seen from the point (8) and the touch sensors (4), not where the point and the landmarks are. Torch tensors in and
    out."""
    import torch

    pos = obs[:, 0:2]
    return torch.cat([obs[:, 2:10] - pos.repeat(1, 4), obs[:, 10:14]], -1)


class LandmarkRouteEnv(gym.Env[np.ndarray, np.ndarray]):
    """A point in the plane driving to four landmarks in the order `order` (see the module docstring).

    Args:
        order: the route, landmark numbers (or text "0,2,1,3"); default `DEMO_ORDER`.
        render_mode: None or "rgb_array".

    Attributes:
        order: the route.
        pos: the point's position (float64).
        landmarks: this episode's landmark positions, shape (4, 2), by label.
        leg: index in `order` of the leg being driven (`len(order)` once all are done).
        wrong_visits: landmarks entered out of turn this episode.
    """

    metadata = {"render_modes": ["rgb_array"], "render_fps": 30}

    IMAGE_SIZE = 256
    """side of rendered images in pixels"""
    COLOURS = ((31, 119, 180), (255, 127, 14), (44, 160, 44), (214, 39, 40))
    """landmark colours by label, those of codes 0-3 in videos (tab10); the path takes the colour of the landmark it
    heads for"""

    def __init__(self, order: str | Sequence[int] = DEMO_ORDER, render_mode: str | None = None) -> None:
        if render_mode is not None and render_mode not in self.metadata["render_modes"]:
            raise UserError(f"Unsupported render_mode {render_mode!r} for LandmarkRoute; use 'rgb_array' or None.")
        self.order = parse_order(order)
        self.render_mode = render_mode
        # positions: as far as 400 steps can go; touch sensors: 0 or 1
        low = np.r_[np.full(OBS_DIM - len(LANDMARKS), -25.0), np.zeros(len(LANDMARKS))].astype(np.float32)
        high = np.r_[np.full(OBS_DIM - len(LANDMARKS), 25.0), np.ones(len(LANDMARKS))].astype(np.float32)
        self.observation_space = spaces.Box(low, high, dtype=np.float32)
        self.action_space = spaces.Box(-1.0, 1.0, (2,), np.float32)
        self.landmarks = np.asarray(LANDMARKS, np.float64)
        self.pos = np.zeros(2)
        self.leg = 0
        self.wrong_visits = 0
        self._inside = np.zeros(len(LANDMARKS), bool)
        self._path: list[tuple[np.ndarray, int]] = []

    @property
    def done(self) -> bool:
        """every leg is done"""
        return self.leg >= len(self.order)

    @property
    def label(self) -> int:
        """oracle sub-task: the landmark the point heads for (the last one once the route is done)"""
        return self.order[min(self.leg, len(self.order) - 1)]

    @property
    def target(self) -> np.ndarray:
        """position of the landmark the point heads for"""
        return self.landmarks[self.label]

    def _obs(self) -> np.ndarray:
        return np.concatenate([self.pos, self.landmarks.reshape(-1), self._inside]).astype(np.float32)

    def _info(self, leg_done: bool = False, wrong: bool = False) -> dict[str, Any]:
        return {"subtask": self.label, "legs_done": self.leg, "leg_done": int(leg_done), "wrong_visit": int(wrong),
                "is_success": bool(self.done and self.wrong_visits == 0)}

    def reset(self, *, seed: int | None = None, options: dict[str, Any] | None = None
              ) -> tuple[np.ndarray, dict[str, Any]]:
        super().reset(seed=seed)
        rng = self.np_random
        self.landmarks = np.asarray(LANDMARKS, np.float64) + rng.uniform(-JITTER, JITTER, (len(LANDMARKS), 2))
        self.pos = rng.uniform(-START_BOX, START_BOX, 2)
        self.leg, self.wrong_visits = 0, 0
        self._inside = np.linalg.norm(self.landmarks - self.pos, axis=1) <= REACH
        self._path = [(self.pos.copy(), self.label)]
        return self._obs(), self._info()

    def step(self, action: Any) -> tuple[np.ndarray, float, bool, bool, dict[str, Any]]:
        act = np.clip(np.asarray(action, np.float64).reshape(-1), -1.0, 1.0)
        if act.shape != (2,) or not np.all(np.isfinite(act)):
            raise ValueError(f"LandmarkRoute action must be 2 finite numbers, got {action!r}.")
        self.pos = self.pos + SPEED * act / max(1.0, float(np.linalg.norm(act)))
        driven = self.label
        reward = -float(np.linalg.norm(self.pos - self.landmarks[driven]))
        inside = np.linalg.norm(self.landmarks - self.pos, axis=1) <= REACH
        entered = inside & ~self._inside
        self._inside = inside
        leg_done = wrong = False
        left = self.order[self.leg - 1] if self.leg > 0 else None  # the landmark the current leg started at
        if not self.done and inside[driven]:
            self.leg += 1
            leg_done = True
        for j in np.flatnonzero(entered):
            if (j != driven or not leg_done) and j != left:
                wrong = True
        self.wrong_visits += int(wrong)
        self._path.append((self.pos.copy(), self.label))
        return self._obs(), reward, self.done, False, self._info(leg_done, wrong)

    def render(self) -> np.ndarray | None:  # type: ignore[override]
        """An RGB image (uint8, 256 x 256 x 3): the landmarks as discs (a ring marks the current target), the path
        coloured by the landmark it was heading for, the point in black."""
        if self.render_mode != "rgb_array":
            return None
        size = self.IMAGE_SIZE
        image = np.full((size, size, 3), 255, np.uint8)
        span = 2 * (max(abs(c) for p in LANDMARKS for c in p) + JITTER + 0.3)
        scale = (size - 1) / span

        def pixel(p: np.ndarray) -> np.ndarray:
            return np.array([(0.5 * span - p[1]) * scale, (p[0] + 0.5 * span) * scale])

        rows, cols = np.mgrid[0:size, 0:size]

        def disc(p: np.ndarray, radius: float, rgb: tuple[int, int, int], ring: bool = False) -> None:
            r, c = pixel(p)
            dist = np.hypot(rows - r, cols - c)
            mask = (np.abs(dist - radius) < 1.5) if ring else dist <= radius
            image[mask] = rgb

        for label, landmark in enumerate(self.landmarks):
            disc(landmark, REACH * scale, self.COLOURS[label])
        if not self.done:
            disc(self.target, REACH * scale + 5, self.COLOURS[self.label], ring=True)
        for (a, label), (b, _) in zip(self._path[:-1], self._path[1:], strict=True):
            pa, pb = pixel(a), pixel(b)
            for s in np.linspace(0.0, 1.0, max(2, int(np.abs(pb - pa).max()) + 1)):
                r, c = np.rint(pa + s * (pb - pa)).astype(int)
                if 0 <= r < size and 0 <= c < size:  # a path that leaves the view is drawn up to its edge
                    image[max(r - 1, 0):r + 2, max(c - 1, 0):c + 2] = self.COLOURS[label]
        disc(self.pos, 4, (0, 0, 0))
        return image
