"""Writing demonstrations as a Minari dataset into any folder, atomically.

Minari builds a dataset below one root folder (`$MINARI_DATASETS_PATH`); `write_dataset` lets it build below a
private temporary root (pointing the variable there for the call), then moves the result into place in one rename.
"""

from __future__ import annotations

import contextlib
import json
import os
import shutil
import warnings
from collections.abc import Iterator, Sequence
from pathlib import Path
from typing import Any

import gymnasium as gym
import numpy as np

from digail.data.trajectory import SUBTASK_KEY, Trajectory
from digail.data.validation import validate_for_space
from digail.envs.registry import make_env
from digail.errors import UserError
from digail.fsio import atomic_dir, json_default
from digail.utils import one_line


@contextlib.contextmanager
def _minari_root_at(root: Path) -> Iterator[None]:
    """Point Minari's root at `root` for the block (Minari reads the variable at every call)."""
    old = os.environ.get("MINARI_DATASETS_PATH")
    os.environ["MINARI_DATASETS_PATH"] = str(root)
    try:
        yield
    finally:
        if old is None:
            os.environ.pop("MINARI_DATASETS_PATH", None)
        else:
            os.environ["MINARI_DATASETS_PATH"] = old


def _to_buffer(traj: Trajectory, episode_id: int, seed: int | None, act_space: gym.Space) -> Any:
    from minari.data_collector import EpisodeBuffer

    n = len(traj)
    last = np.zeros(n, dtype=bool)
    last[-1] = True
    acts = (traj.acts.astype(np.int64) + int(act_space.start) if isinstance(act_space, gym.spaces.Discrete)
            else traj.acts.astype(np.float32))
    rews = np.zeros(n, dtype=np.float32) if traj.rews is None else np.asarray(traj.rews, dtype=np.float32)
    infos = None if traj.subtasks is None else {SUBTASK_KEY: np.asarray(traj.subtasks, dtype=np.int64)}
    return EpisodeBuffer(id=episode_id, seed=seed, observations=traj.obs.astype(np.float32), actions=acts,
                         rewards=rews, terminations=last & traj.terminated,
                         truncations=last & (not traj.terminated), infos=infos)


def write_dataset(trajs: Sequence[Trajectory], path: str | os.PathLike[str], env_id: str | None, dataset_id: str, *,
                  force: bool = False, seeds: Sequence[int] | None = None, author: str | None = "digail",
                  description: str | None = None, algorithm_name: str | None = None,
                  observation_space: gym.Space | None = None, action_space: gym.Space | None = None,
                  extra_metadata: dict[str, Any] | None = None, compact: bool = True,
                  env_kwargs: dict[str, Any] | None = None) -> Path:
    """Write trajectories as a Minari dataset folder at `path`, atomically.

    Everything is written into a temporary sibling folder that is renamed to `path` only on success: on any
    error nothing is left at `path` (an existing folder is replaced only with `force`, and only at the end).

    Args:
        trajs: the episodes; labels (if any) go to the episode infos under "subtask" (T + 1 entries).
        path: the dataset folder to create (it will hold `data/metadata.json` and `data/main_data.hdf5`).
        env_id: the environment the data comes from; its spec (id, entry point, kwargs, time limit) and spaces
            are stored so readers can recreate the env and check a dataset against one. None: data without an
            environment (imported demonstrations); then both spaces must be given and no env spec is stored.
        dataset_id: Minari id stored in the metadata, e.g. "digail/circleworld/expert-v0".
        force: replace an existing folder at `path`.
        seeds: reset seed of each episode, stored per episode (Minari's `seed` attribute).
        author: Minari metadata: who made the data.
        description: Minari metadata: what the data is.
        algorithm_name: Minari metadata: what produced the data.
        observation_space: overrides the env's observation space (e.g. a flattened dict observation space).
        action_space: overrides the env's action space.
        extra_metadata: JSON-serialisable record stored under the metadata key "digail" (digail adds
            `rewards_recorded`).
        compact: rewrite Minari's chunked HDF5 file with contiguous arrays (about 4x smaller for short
            episodes; see `_compact_hdf5`).
        env_kwargs: keyword arguments `env_id` is made with (kept in the stored env spec).

    Returns:
        `path` as a `Path`.

    Raises:
        UserError: existing `path` without `force`, unknown env, no episodes, mixed labels, data that does not
            match the spaces.
    """
    from minari import create_dataset_from_buffers
    from minari.dataset.minari_dataset import parse_dataset_id

    path = Path(path)
    trajs = list(trajs)
    if path.exists() and not force:
        raise UserError(f"output folder {path} already exists; choose another --out or pass --force.")
    if not trajs:
        raise UserError("no episodes to write; record at least one episode.")
    try:
        parse_dataset_id(dataset_id)
    except ValueError as exc:
        raise UserError(f"invalid Minari dataset id {dataset_id!r}; use the form namespace/name-v0.") from exc
    if seeds is not None and len(seeds) != len(trajs):
        raise UserError(f"got {len(seeds)} seeds for {len(trajs)} episodes; give one seed per episode.")
    labelled = [t.subtasks is not None for t in trajs]
    if any(labelled) and not all(labelled):
        raise UserError(f"{sum(labelled)} of {len(trajs)} episodes have sub-task labels; label all or none.")
    if env_id is None:
        if observation_space is None or action_space is None:
            raise UserError("data without an environment needs its observation and action spaces; pass both.")
        spec, obs_space, act_space = None, observation_space, action_space
    else:
        env = make_env(env_id, **(env_kwargs or {}))
        try:
            spec = env.spec
            obs_space = observation_space or env.observation_space
            act_space = action_space or env.action_space
        finally:
            env.close()
    for i, traj in enumerate(trajs):
        validate_for_space(f"episode {i}", traj, obs_space, act_space)
    buffers = [_to_buffer(t, i, None if seeds is None else int(seeds[i]), act_space)
               for i, t in enumerate(trajs)]
    record = {"rewards_recorded": all(t.rews is not None for t in trajs), **(extra_metadata or {})}
    try:
        record = json.loads(json.dumps(record, default=json_default))
    except (TypeError, ValueError) as exc:
        raise UserError(f"extra dataset metadata is not JSON-serialisable ({one_line(exc)}).") from exc

    with atomic_dir(path, force=force) as tmp:
        root = (tmp / ".minari-root").resolve()  # Minari mis-joins relative roots
        with _minari_root_at(root), warnings.catch_warnings():
            warnings.simplefilter("ignore")  # Minari nags about optional metadata (permalink, eval env)
            mds = create_dataset_from_buffers(
                dataset_id, buffers, env=spec, eval_env=None, algorithm_name=algorithm_name, author=author,
                description=description, observation_space=obs_space, action_space=act_space,
            )
            mds.storage.update_metadata({"digail": record})
        os.replace(root / dataset_id / "data", tmp / "data")
        shutil.rmtree(root)
        if compact:
            _compact_hdf5(tmp / "data" / "main_data.hdf5")
    return path


def _compact_hdf5(file: Path) -> None:
    """Rewrite an HDF5 file with contiguous (unchunked) datasets, same groups, data and attributes.

    Minari writes every per-episode array as a resizable chunked dataset, whose minimum chunk makes short
    episodes cost ~20 KB each; contiguous storage is about 4x smaller for our datasets and reads identically.
    The copy's datasets are no longer resizable, which only matters for appending to an existing episode.
    """
    import h5py

    def copy(src: h5py.Group, dst: h5py.Group) -> None:
        dst.attrs.update(dict(src.attrs))
        for key, item in src.items():
            if isinstance(item, h5py.Group):
                copy(item, dst.create_group(key, track_order=True))
            else:
                out = dst.create_dataset(key, data=item[()], dtype=item.dtype)
                out.attrs.update(dict(item.attrs))

    compact = file.with_name(file.name + ".compact")
    with h5py.File(file, "r") as src, h5py.File(compact, "w", track_order=True) as dst:
        copy(src, dst)
    os.replace(compact, file)
