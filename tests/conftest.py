"""Shared fixtures: small in-memory demonstrations from the scripted experts."""

from __future__ import annotations

import numpy as np
import pytest
import torch

import digail  # noqa: F401  (registers the envs)
from digail.data.trajectory import Trajectory
from digail.envs import make_env
from digail.experts.scripted import get_scripted_expert

torch.set_num_threads(1)


def expert_trajectories(env_id: str, episodes: int, seed: int = 0) -> list[Trajectory]:
    """Roll out the scripted expert; labels kept."""
    env = make_env(env_id)
    expert = get_scripted_expert(env_id)
    assert expert is not None
    out = []
    for e in range(episodes):
        o, info = env.reset(seed=seed + e)
        obs, acts, labels = [o], [], [info["subtask"]]
        while True:
            a = expert(env)
            o, _, term, trunc, info = env.step(a)
            obs.append(o)
            acts.append(a)
            labels.append(info["subtask"])
            if term or trunc:
                break
        out.append(Trajectory(np.asarray(obs, np.float32), np.asarray(acts), None, np.asarray(labels, np.int64),
                              bool(term)))
    env.close()
    return out


@pytest.fixture(scope="session")
def circle_demos() -> list[Trajectory]:
    return expert_trajectories("digail/CircleWorld-v0", 12)


@pytest.fixture(scope="session")
def rooms_demos() -> list[Trajectory]:
    return expert_trajectories("digail/FourRooms-v0", 100)
