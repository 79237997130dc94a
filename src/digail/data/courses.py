"""Recording the segmentation benchmark's waypoint courses with Minari's own API, as a user records their data.

`record_course` drives the course env with the scripted `WaypointExpert`, keeps each episode's observations,
actions, rewards and infos (the oracle label "subtask" among them, where `load_dataset` reads it) in a
`minari.data_collector.EpisodeBuffer`, and builds the dataset with `minari.create_dataset_from_buffers` below the
Minari root given: Minari's documented API, nothing digail-specific on the writing side. (`minari.DataCollector`
would do the stepping too, but it needs jax, which `pip install minari` does not bring.)
"""

from __future__ import annotations

import os
import warnings
from pathlib import Path

import numpy as np

from digail.data.minari_write import _minari_root_at
from digail.envs.registry import make_env
from digail.envs.waypoints import COURSE_ENV_ID, COURSES, WaypointCourseEnv, WaypointExpert
from digail.errors import UserError


def course_dataset_id(name: str, seed: int = 0) -> str:
    """Minari id of course `name` recorded with `seed`."""
    return f"segbench/{name}-s{seed}-v0"


def record_course(name: str, root: str | os.PathLike[str], seed: int = 0, episodes: int | None = None) -> Path:
    """Record course `name` (`digail.envs.waypoints.COURSES`) below Minari root `root`; returns the dataset folder.

    An existing dataset of the same id is kept as it is (the recording is deterministic in `seed`).
    """
    import minari
    from minari.data_collector import EpisodeBuffer

    if name not in COURSES:
        raise UserError(f"unknown course {name!r}; choose one of {', '.join(COURSES)}.")
    course = COURSES[name]
    dataset_id = course_dataset_id(name, seed)
    root = Path(root).resolve()  # Minari resolves relative roots against its own folders
    folder = root / dataset_id
    if (folder / "data" / "metadata.json").is_file():
        return folder
    with _minari_root_at(root):
        env = make_env(COURSE_ENV_ID, **course.kwargs)
        inner = env.unwrapped
        assert isinstance(inner, WaypointCourseEnv)
        expert = WaypointExpert(inner, course.noise, seed=seed)
        buffers = []
        for ep in range(course.episodes if episodes is None else episodes):
            ep_seed = seed * 100_000 + ep
            obs, info = env.reset(seed=ep_seed)
            observations, actions, rewards, labels = [obs], [], [], [info["subtask"]]
            terminated = truncated = False
            while not (terminated or truncated):
                act = expert(obs)
                obs, reward, terminated, truncated, info = env.step(act)
                observations.append(obs)
                actions.append(act)
                rewards.append(reward)
                labels.append(info["subtask"])
            n = len(actions)
            buffers.append(EpisodeBuffer(
                id=ep, seed=ep_seed, observations=np.asarray(observations, np.float32),
                actions=np.asarray(actions), rewards=np.asarray(rewards, np.float64),
                terminations=np.r_[np.zeros(n - 1, bool), terminated],
                truncations=np.r_[np.zeros(n - 1, bool), truncated],
                infos={"subtask": np.asarray(labels, np.int64)}))
        with warnings.catch_warnings():  # Minari asks for an author e-mail and a code permalink: not ours to give
            warnings.simplefilter("ignore", UserWarning)
            minari.create_dataset_from_buffers(dataset_id, buffers, env=env,
                                               algorithm_name="scripted waypoint expert",
                                               description=course.description)
        env.close()
    return folder
