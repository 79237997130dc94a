"""Reference rows for the landmark route (docs/experiments/2026-12-05-landmark-route.md): the scripted expert on the
demonstrated route and on one never demonstrated, a random and a do-nothing policy, and the expert of the
demonstrated route driven on the new route; measured as `digail evaluate` measures an agent (100 episodes from seed
10000, env reward, success, legs done, wrong visits). Also renders the expert's videos.

    MUJOCO_GL=egl python benchmarks/studies/route_reference.py
        -> benchmarks/results/landmark-route/landmark_route_reference.json,
           benchmarks/results/videos/landmarkroute/expert_{demonstrated,reversed}_seed10000.mp4
"""

from __future__ import annotations

import json
import time
from pathlib import Path
from typing import Any

import numpy as np

import digail  # noqa: F401  (registers the envs)
from digail.envs import make_env
from digail.envs.episodes import play_episodes
from digail.envs.landmark_route import DEMO_ORDER, LANDMARK_NAMES, REACH, ROUTE_ENV_ID
from digail.eval.returns import summarize
from digail.experts.scripted import route_expert
from digail.viz.video import annotate, write_mp4_gif

HERE = Path(__file__).resolve().parents[1]
NEW_ORDER = (3, 2, 1, 0)


class DemonstratedRoute:
    """The expert of the demonstrated route, whatever route the env asks for (its own count of the legs): what a
    policy that can only replay the demonstrations does on a new route."""

    def __init__(self) -> None:
        self.leg = 0

    def __call__(self, env: Any, obs: Any) -> np.ndarray:
        base = env.unwrapped
        if len(base._path) == 1:  # a fresh episode
            self.leg = 0
        target = base.landmarks[DEMO_ORDER[min(self.leg, len(DEMO_ORDER) - 1)]]
        if self.leg < len(DEMO_ORDER) and np.linalg.norm(target - base.pos) <= REACH:
            self.leg += 1
            target = base.landmarks[DEMO_ORDER[min(self.leg, len(DEMO_ORDER) - 1)]]
        gap = target - base.pos
        return (gap / max(float(np.linalg.norm(gap)), 1e-9)).astype(np.float32)


def measure(order: tuple[int, ...], policy: Any, episodes: int, seed: int) -> dict[str, Any]:
    env = make_env(ROUTE_ENV_ID, order=order)
    started = time.perf_counter()
    eps = play_episodes(env, policy, episodes, seed)
    env.close()
    return {"order": list(order), **summarize(eps, ROUTE_ENV_ID),
            "success_rate": float(np.mean([bool(e.final_info["is_success"]) for e in eps])),
            "time_s": round(time.perf_counter() - started, 1)}


def video(order: tuple[int, ...], seed: int, stem: Path) -> Path:
    """One expert episode on `order`, each frame captioned with the step and the landmark the point heads for."""
    env = make_env(ROUTE_ENV_ID, order=order, render_mode="rgb_array")
    env.reset(seed=seed)
    frames, done, t = [], False, 0
    while True:
        base = env.unwrapped
        frames.append(annotate(env.render(), f"expert  step {t}  to {LANDMARK_NAMES[base.label]}", base.label))
        if done:
            break
        _, _, terminated, truncated, _ = env.step(route_expert(env))
        done, t = terminated or truncated, t + 1
    env.close()
    return write_mp4_gif(frames, stem)[0]


def main(episodes: int = 100, seed: int = 10_000) -> None:
    rng = np.random.default_rng(0)
    rows = {
        "expert, demonstrated route": measure(DEMO_ORDER, lambda env, obs: route_expert(env), episodes, seed),
        "expert, reversed route": measure(NEW_ORDER, lambda env, obs: route_expert(env), episodes, seed),
        "random actions": measure(DEMO_ORDER, lambda env, obs: rng.uniform(-1, 1, 2).astype(np.float32),
                                  episodes, seed),
        "do nothing": measure(DEMO_ORDER, lambda env, obs: np.zeros(2, np.float32), episodes, seed),
        "demonstrated route driven on the reversed route": measure(NEW_ORDER, DemonstratedRoute(), episodes, seed),
    }
    for name, row in rows.items():
        print(f"{name}: {json.dumps(row)}")
    out = HERE / "results" / "landmark-route" / "landmark_route_reference.json"
    out.write_text(json.dumps({"command": "python benchmarks/studies/route_reference.py", "episodes": episodes,
                               "seed": seed, "rows": rows}, indent=1) + "\n")
    folder = HERE / "results" / "videos" / "landmarkroute"
    for name, order in (("demonstrated", DEMO_ORDER), ("reversed", NEW_ORDER)):
        print("wrote", video(order, seed, folder / f"expert_{name}_seed{seed}"))


if __name__ == "__main__":
    main()
