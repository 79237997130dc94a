"""Reference rows for Fetch (docs/fetch.md): the scripted expert and a do-nothing policy, measured as
`digail evaluate` measures an agent (100 episodes from seed 10000, dense `mean_return`, sparse return, success,
grasp and lift rates).

    python benchmarks/studies/fetch_reference.py
"""

from __future__ import annotations

import json
import time

import numpy as np

import digail  # noqa: F401  (registers the envs)
from digail.envs import make_env
from digail.envs.episodes import play_episodes
from digail.eval.returns import expert_summary, summarize

ENV = "digail/FetchPickAndPlace-v4"


def main(episodes: int = 100, seed: int = 10_000) -> None:
    started = time.perf_counter()
    print("scripted expert", json.dumps(expert_summary(ENV, episodes, seed)),
          f"{time.perf_counter() - started:.0f}s")
    started = time.perf_counter()
    env = make_env(ENV)
    eps = play_episodes(env, lambda env, obs: np.zeros(4, np.float32), episodes, seed)
    env.close()
    print("do nothing", json.dumps(summarize(eps, ENV)), f"{time.perf_counter() - started:.0f}s")


if __name__ == "__main__":
    main()
