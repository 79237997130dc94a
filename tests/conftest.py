"""Shared fixtures: small in-memory demonstrations from the scripted experts."""

from __future__ import annotations

import importlib.util
import sys
from pathlib import Path
from types import ModuleType

import pytest
import torch

import digail  # noqa: F401  (registers the envs)
from digail.data.demos import rollout_episodes
from digail.data.trajectory import Trajectory
from digail.envs import make_env
from digail.experts import expert_for

torch.set_num_threads(1)

REPO = Path(__file__).resolve().parents[1]


def repo_module(path: str) -> ModuleType:
    """The benchmark or script at `path` (relative to the repository) as a module, loaded from its file once:
    tests use the harnesses without putting their folders on `sys.path`, where their short names could shadow
    installed modules."""
    name = Path(path).stem
    if name in sys.modules and getattr(sys.modules[name], "__file__", None) == str(REPO / path):
        return sys.modules[name]
    spec = importlib.util.spec_from_file_location(name, REPO / path)
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    sys.modules[name] = module  # dataclasses and pickle look a class's module up by name
    spec.loader.exec_module(module)
    return module


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
