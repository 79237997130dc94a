"""Shared fixtures: small in-memory demonstrations from the scripted experts."""

from __future__ import annotations

import pytest
import torch

import digail  # noqa: F401  (registers the envs)
from digail.data.demos import rollout_episodes
from digail.data.trajectory import Trajectory
from digail.envs import make_env
from digail.experts import expert_for

torch.set_num_threads(1)


@pytest.fixture(autouse=True, scope="session")
def _private_cache(tmp_path_factory: pytest.TempPathFactory) -> None:
    """Measured expert returns go to a cache of this test session, not the user's."""
    import os

    os.environ["DIGAIL_CACHE_DIR"] = str(tmp_path_factory.mktemp("cache"))


def expert_trajectories(env_id: str, episodes: int, seed: int = 0) -> list[Trajectory]:
    """Roll out the scripted expert; labels kept."""
    env = make_env(env_id)
    policy, kind = expert_for(env_id)
    assert kind == "scripted"
    trajs = rollout_episodes(env, policy, episodes, seed, progress=False)
    env.close()
    return trajs


@pytest.fixture(scope="session")
def circle_demos() -> list[Trajectory]:
    return expert_trajectories("digail/CircleWorld-v0", 12)


@pytest.fixture(scope="session")
def rooms_demos() -> list[Trajectory]:
    return expert_trajectories("digail/FourRooms-v0", 100)
