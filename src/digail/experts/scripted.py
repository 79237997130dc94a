"""Scripted experts: closed-form controllers that read the env's true state (through `env.unwrapped`).

Each expert is a function `expert(env) -> action` for the env's current state; `SCRIPTED_EXPERTS` says which env
each drives and `get_scripted_expert` finds it. They are
deterministic, so demonstrations recorded from a seeded env are reproducible.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from typing import Any

import gymnasium as gym
import numpy as np

from digail.config import FINAL_EVAL_SEED
from digail.envs.circle_world import CircleWorldEnv, reference_point, reversed_reference_point
from digail.envs.four_rooms import CORRIDORS, FourRoomsEnv, shortest_paths_to
from digail.envs.landmark_route import DEMO_ORDER, ROUTE_ENV_ID, LandmarkRouteEnv
from digail.experts.fetch import fetch_expert
from digail.experts.metaworld import METAWORLD_EXPERTS


def _unwrapped(env: gym.Env, cls: type) -> Any:
    base = env.unwrapped
    if not isinstance(base, cls):
        raise TypeError(f"This expert drives {cls.__name__}, got {type(base).__name__}.")
    return base


def four_rooms_expert(env: gym.Env) -> int:
    """Shortest-path action towards the apple (ties: up, right, down, left first); 0 once on the apple.

    The label in `info["subtask"]` follows the same path (`digail.envs.four_rooms.shortest_paths_to`).
    """
    base: FourRoomsEnv = _unwrapped(env, FourRoomsEnv)
    x, y = base.agent
    return int(shortest_paths_to(base.apple).action[y, x])


def circle_expert(env: gym.Env) -> np.ndarray:
    """Unit direction from the current position to the next reference point, float32 of shape (2,).

    Clockwise for the first `steps_per_circle` steps, then back counter-clockwise. A step of the env's chord
    length in this direction lands on the reference point, and aiming at it afresh each step keeps rounding
    errors from accumulating. Zero action once the episode's steps are used up.
    """
    base: CircleWorldEnv = _unwrapped(env, CircleWorldEnv)
    if base.t >= base.episode_steps:
        return np.zeros(2, dtype=np.float32)
    offset = reference_point(base.radius, base.t + 1, base.steps_per_circle) - base.position
    norm = float(np.linalg.norm(offset))
    if norm < 1e-12:
        return np.zeros(2, dtype=np.float32)
    return (offset / norm).astype(np.float32)


def circle_reversed_expert(env: gym.Env) -> np.ndarray:
    """`circle_expert` for the order never demonstrated: counter-clockwise first, then clockwise
    (`digail.envs.circle_world.reversed_reference_point`); the reference a reversed composition is scored against."""
    base: CircleWorldEnv = _unwrapped(env, CircleWorldEnv)
    if base.t >= base.episode_steps:
        return np.zeros(2, dtype=np.float32)
    offset = reversed_reference_point(base.radius, base.t + 1, base.steps_per_circle) - base.position
    norm = float(np.linalg.norm(offset))
    return (offset / norm).astype(np.float32) if norm >= 1e-12 else np.zeros(2, dtype=np.float32)


class FourRoomsRouteExpert:
    """Shortest paths through the corridors of `route` in turn, then to the apple: a route the shortest-path
    expert may never take (e.g. the long way round). Call `reset()` at every episode start."""

    def __init__(self, route: Sequence[int]) -> None:
        self.route = [int(c) for c in route]
        self.next = 0

    def reset(self) -> None:
        """Start again at the route's first corridor."""
        self.next = 0

    def __call__(self, env: gym.Env) -> int:
        base: FourRoomsEnv = _unwrapped(env, FourRoomsEnv)
        while self.next < len(self.route) and base.agent == CORRIDORS[self.route[self.next]]:
            self.next += 1
        target = CORRIDORS[self.route[self.next]] if self.next < len(self.route) else base.apple
        x, y = base.agent
        return int(shortest_paths_to(target).action[y, x])


def route_expert(env: gym.Env) -> np.ndarray:
    """Unit direction from the point to the landmark of the current leg, float32 of shape (2,), for any order.

    Straight legs between the landmarks never come within reach of a third one, so the expert never visits a
    landmark out of turn; zero action once the route is done.
    """
    base: LandmarkRouteEnv = _unwrapped(env, LandmarkRouteEnv)
    gap = base.target - base.pos
    norm = float(np.linalg.norm(gap))
    if base.done or norm < 1e-12:
        return np.zeros(2, dtype=np.float32)
    return (gap / norm).astype(np.float32)


def evaluate_route_expert(episodes: int = 100, seed: int = FINAL_EVAL_SEED,
                          order: str | Sequence[int] = DEMO_ORDER) -> dict[str, Any]:
    """Success rate, returns and lengths of `route_expert` on the route `order` over `episodes` episodes (episode
    i: seed + i), measured as `digail evaluate` measures an agent (env reward, `is_success` of the last step)."""
    from digail.envs import make_env
    from digail.envs.episodes import play_episodes
    from digail.envs.landmark_route import parse_order

    env = make_env(ROUTE_ENV_ID, order=order)
    try:
        eps = play_episodes(env, lambda env, obs: route_expert(env), episodes, seed, keep=True)
    finally:
        env.close()
    returns = [ep.ret for ep in eps]
    return {"env_id": ROUTE_ENV_ID, "order": list(parse_order(order)), "episodes": episodes, "seed": seed,
            "success_rate": float(np.mean([bool(ep.final_info["is_success"]) for ep in eps])),
            "mean": float(np.mean(returns)), "std": float(np.std(returns)),
            "mean_length": float(np.mean([ep.length for ep in eps])),
            "min_length": int(min(ep.length for ep in eps)), "max_length": int(max(ep.length for ep in eps)),
            "wrong_visits": int(sum(sum(info["wrong_visit"] for info in ep.infos) for ep in eps))}


SCRIPTED_EXPERTS: dict[str, Callable[[gym.Env], Any]] = {
    "digail/FourRooms-v0": four_rooms_expert,
    "digail/CircleWorld-v0": circle_expert,
    "digail/FetchPickAndPlace-v4": fetch_expert,
    "digail/FetchPickAndPlaceRelative-v4": fetch_expert,
    "digail/LandmarkRoute-v0": route_expert,
    **METAWORLD_EXPERTS,
}
"""env id -> its scripted expert"""


def get_scripted_expert(env_id: str) -> Callable[[gym.Env], Any] | None:
    """The scripted expert of `env_id`, or None when the env has none (use an RL expert instead)."""
    return SCRIPTED_EXPERTS.get(env_id)
