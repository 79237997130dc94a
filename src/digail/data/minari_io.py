"""Demonstrations on disk as Minari datasets: write, find, read and validate them.

A Minari dataset is a folder `<dataset>/data/` holding `metadata.json` (dataset id, env spec, serialised
spaces) and `main_data.hdf5` (one group per episode). Minari itself addresses datasets by id below one root
folder (`$MINARI_DATASETS_PATH`, default `~/.minari/datasets`); here a user may also pass any dataset folder:

- writing: `write_dataset` lets Minari build the dataset below a private temporary root (pointing
  `MINARI_DATASETS_PATH` there for the call), then moves the result to the requested folder in one rename;
- reading: `load_dataset` resolves a folder path or an id (shipped datasets first, then the Minari root) to
  the `data/` folder and opens it with `minari.MinariDataset`, which takes a path directly.

Conventions (what `Trajectory` expects): `T` actions, `T + 1` observations; oracle sub-task labels live in the
episode infos under `"subtask"` with `T + 1` entries (label at reset, then after each step); the last step is
either a termination or a truncation. Dict observations (e.g. the robotics envs) are flattened on reading by a
hook (`obs_hook`, default `flatten_dict_obs`), which also decides the dataset's observation space.
"""

from __future__ import annotations

import json
import os
import warnings
from collections.abc import Callable
from pathlib import Path
from typing import Any

import gymnasium as gym
import numpy as np

from digail.data.trajectory import SUBTASK_KEY, Dataset, Trajectory
from digail.data.validation import check_actions, read_labels
from digail.errors import UserError
from digail.user_envs import register_recorded_env
from digail.utils import one_line

SHIPPED_ROOT = Path(__file__).resolve().parent.parent / "datasets"
"""Minari root of the datasets shipped inside the package (ids resolve here first)."""


ObsHook = Callable[[Any, gym.Space], np.ndarray]
"""Turns one episode's stored observations (array, dict of arrays, ...) into a `(T + 1, d)` array."""


# --------------------------------------------------------------------------------------------- locations
def minari_root() -> Path:
    """The user's Minari root: `$MINARI_DATASETS_PATH`, else `~/.minari/datasets` (not created here)."""
    env = os.environ.get("MINARI_DATASETS_PATH")
    return Path(env) if env else Path.home() / ".minari" / "datasets"


def shipped_dataset_ids() -> list[str]:
    """Ids of the datasets shipped with digail."""
    return sorted(p.parent.parent.relative_to(SHIPPED_ROOT).as_posix()
                  for p in SHIPPED_ROOT.glob("**/data/metadata.json"))


def _data_dir(folder: Path) -> Path | None:
    """The folder holding `metadata.json`, given a dataset folder or its `data/` folder."""
    if (folder / "data" / "metadata.json").is_file():
        return folder / "data"
    if (folder / "metadata.json").is_file():
        return folder
    return None


def _missing_message(path_or_id: str) -> str:
    ids = shipped_dataset_ids()
    listing = f"pass an id such as {', '.join(ids)}" if ids else "pass the id of a dataset in the Minari root"
    return (f"no Minari dataset at {path_or_id}; create one with `digail demos ENV --out {path_or_id}` or "
            f"{listing} (searched the folder path, {SHIPPED_ROOT} and {minari_root()}).")


def resolve_dataset(path_or_id: str | os.PathLike[str]) -> Path:
    """The dataset folder for a folder path or a Minari id (shipped root first, then the Minari root).

    Raises:
        UserError: when nothing there holds a Minari dataset.
    """
    text = os.fspath(path_or_id)
    candidates = [Path(text).expanduser()]
    outside = []
    if not Path(text).is_absolute():
        for root in (SHIPPED_ROOT, minari_root()):
            # an id stays below its root: `..` must not reach datasets (or any folder) elsewhere on the machine
            if os.path.normpath(root / text).startswith(os.path.join(os.path.normpath(root), "")):
                candidates.append(root / text)
            else:
                outside.append(root)
    for folder in candidates:
        data = _data_dir(folder)
        if data is not None:
            return data.parent
    if Path(text).expanduser().is_file():
        raise UserError(f"{text} is a file, not a Minari dataset folder; turn it into one with `digail import {text} "
                        "--env ENV --out FOLDER`, or pass it to `digail run ENV --demos`.")
    folder = Path(text).expanduser()
    if folder.is_dir() and any(folder.iterdir()):  # never propose writing into a folder that holds the user's data
        raise UserError(f"{text} is a folder but not a Minari dataset (no data/metadata.json); if it holds "
                        f"demonstrations of another tool (a LeRobot dataset, imitation's trajectories), turn them into "
                        f"one with `digail import {text} --out NEW_FOLDER`, or pass it to `digail run ENV --demos`.")
    if outside:
        raise UserError(f"dataset id {text!r} leads outside the Minari root {outside[-1]}; an id names a dataset "
                        "below the root, so pass a dataset folder path instead.")
    raise UserError(_missing_message(text))


def _read_metadata(data: Path) -> dict[str, Any]:
    try:
        with open(data / "metadata.json") as f:
            metadata = json.load(f)
    except (OSError, ValueError, RecursionError) as exc:  # RecursionError: JSON nested beyond the parser's depth
        raise UserError(f"cannot read {data / 'metadata.json'} ({one_line(exc)}); the dataset is corrupt, "
                        "re-create it with `digail demos`.") from exc
    if not isinstance(metadata, dict):
        raise UserError(f"{data / 'metadata.json'} is not a JSON object; the dataset is corrupt, re-create "
                        "it with `digail demos`.")
    return metadata


def _env_id_from_metadata(metadata: dict[str, Any]) -> str | None:
    spec = metadata.get("env_spec")
    if not spec:
        return None
    try:
        env_id = json.loads(spec)["id"]
    except (ValueError, KeyError, TypeError):
        return None
    return str(env_id)


def dataset_env_id(path_or_id: str | os.PathLike[str]) -> str:
    """The env id a dataset was recorded in, read from its metadata only (cheap).

    Raises:
        UserError: when the dataset is missing, unreadable, or records no environment.
    """
    folder = resolve_dataset(path_or_id)
    env_id = _env_id_from_metadata(_read_metadata(folder / "data"))
    if env_id is None:
        raise UserError(f"dataset {folder} records no environment id; pass the environment explicitly "
                        "with --env.")
    return env_id


def dataset_metadata(path_or_id: str | os.PathLike[str]) -> tuple[Path, dict[str, Any]]:
    """A dataset's folder and its `data/metadata.json`, read alone (cheap: no episode is loaded)."""
    folder = resolve_dataset(path_or_id)
    return folder, _read_metadata(folder / "data")


# ------------------------------------------------------------------------------------------------ reading
def flatten_dict_obs(obs: Any, space: gym.Space) -> np.ndarray:
    """Default `ObsHook`: concatenate the parts of dict observations in the space's key order.

    The order and layout match `gymnasium.wrappers.FlattenObservation` (for Box parts), so a policy trained on
    the result runs in `FlattenObservation(env)`. Plain arrays are returned unchanged.
    """
    if isinstance(space, gym.spaces.Dict):
        if not isinstance(obs, dict):
            raise UserError("stored observations are not a dict although the observation space is one; the "
                            "dataset is corrupt, re-create it.")
        parts = [flatten_dict_obs(obs[key], sub) for key, sub in space.spaces.items()]
        return np.concatenate([p.reshape(len(p), -1) for p in parts], axis=1)
    if isinstance(space, gym.spaces.Box):
        return np.asarray(obs)
    raise UserError(f"observation space {space} is not supported; pass an obs_hook that turns it into "
                    "arrays.")


def _hooked_space(space: gym.Space, hook: ObsHook | None, sample: np.ndarray) -> gym.Space:
    if isinstance(space, gym.spaces.Box) and hook is None:
        return space
    if hook is None and isinstance(space, gym.spaces.Dict):
        return gym.spaces.flatten_space(space)
    return gym.spaces.Box(-np.inf, np.inf, shape=sample.shape[1:], dtype=np.float32)


def load_dataset(path_or_id: str | os.PathLike[str], *, obs_hook: ObsHook | None = None) -> Dataset:
    """Read and validate a Minari dataset.

    Args:
        path_or_id: a dataset folder (the one holding `data/`, or `data/` itself) or a Minari dataset id,
            looked up in the shipped datasets first, then in `$MINARI_DATASETS_PATH` (or
            `~/.minari/datasets`).
        obs_hook: turns one episode's stored observations into a `(T + 1, d)` array; the default flattens dict
            observations (see `flatten_dict_obs`) and leaves Box observations alone. Put custom preprocessing
            of foreign datasets (e.g. picking keys of a robotics dict) here.

    Returns:
        The validated `Dataset`: float32 observations, float32 (continuous) or int64 (discrete) actions,
        float32 rewards (None when the writer recorded none), labels from `infos["subtask"]` where present.

    Raises:
        UserError: one sentence naming the problem: missing or corrupt dataset, NaN/inf values, shapes or
            dtypes that do not match the stored spaces, unsupported spaces, partial labels.
    """
    folder = resolve_dataset(path_or_id)
    data = folder / "data"
    metadata = _read_metadata(data)
    try:
        from minari import MinariDataset

        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            mds = MinariDataset(data)
            episodes = list(mds.iterate_episodes())
        obs_space, act_space = mds.observation_space, mds.action_space
    except UserError:
        raise
    except Exception as exc:  # h5py / json / minari raise many types for a damaged file
        raise UserError(f"cannot read the Minari dataset at {folder} ({one_line(exc)}); the files are "
                        "corrupt or from an unsupported Minari version, re-create it with `digail demos`.") \
            from exc
    if not episodes:
        raise UserError(f"the Minari dataset at {folder} has no episodes; record some with `digail demos`.")
    if not isinstance(act_space, gym.spaces.Box | gym.spaces.Discrete):
        raise UserError(f"dataset {folder} has action space {act_space}; only Box and Discrete actions are "
                        "supported.")
    rewards_recorded = bool(metadata.get("digail", {}).get("rewards_recorded", True))
    hook = obs_hook or flatten_dict_obs
    trajs: list[Trajectory] = []
    for i, ep in enumerate(episodes):
        where = f"dataset {folder} episode {i}"
        obs = np.asarray(hook(ep.observations, obs_space))
        trajs.append(_episode_to_traj(where, obs, ep, obs_space, act_space, obs_hook, rewards_recorded))
    labelled = [t.subtasks is not None for t in trajs]
    if any(labelled) and not all(labelled):
        raise UserError(f"dataset {folder} has '{SUBTASK_KEY}' labels in {sum(labelled)} of {len(trajs)} "
                        "episodes; label all episodes or none.")
    out_obs_space = _hooked_space(obs_space, obs_hook, trajs[0].obs)
    register_recorded_env(metadata.get("env_spec"))  # an env defined outside digail, made from its entry point
    return Dataset(trajs=trajs, env_id=_env_id_from_metadata(metadata), observation_space=out_obs_space,
                   action_space=act_space, dataset_id=str(metadata.get("dataset_id", folder.name)),
                   path=folder, metadata=metadata)


def _episode_to_traj(where: str, obs: np.ndarray, ep: Any, obs_space: gym.Space, act_space: gym.Space,
                     obs_hook: ObsHook | None, rewards_recorded: bool) -> Trajectory:
    acts = np.asarray(ep.actions)
    n_steps = len(acts)
    if n_steps == 0:
        raise UserError(f"{where} has no steps; drop it or re-record the dataset.")
    if obs.ndim < 1 or len(obs) != n_steps + 1:
        raise UserError(f"{where} has {len(obs)} observations for {n_steps} actions (expected one more "
                        "observation than actions); the dataset is malformed.")
    if isinstance(obs_space, gym.spaces.Box) and obs_hook is None and obs.shape[1:] != obs_space.shape:
        raise UserError(f"{where} has observations of shape {obs.shape[1:]} but the dataset's observation "
                        f"space has shape {obs_space.shape}; the dataset is malformed.")
    if not np.issubdtype(obs.dtype, np.number):
        raise UserError(f"{where} has non-numeric observations (dtype {obs.dtype}); the dataset is "
                        "malformed.")
    if not np.all(np.isfinite(obs)):
        raise UserError(f"{where} has NaN or inf values in its observations; re-record the dataset or drop "
                        "that episode.")
    if obs.dtype.itemsize > 4 and obs.size and np.abs(obs).max() > np.finfo(np.float32).max:
        raise UserError(f"{where} has observations beyond float32's range (about 3.4e38 in size), which is how "
                        "digail holds demonstrations; rescale them or drop that episode.")
    acts = check_actions(where, acts, act_space)
    rews = np.asarray(ep.rewards, dtype=np.float32).reshape(-1)
    if rews.shape != (n_steps,):
        raise UserError(f"{where} has {rews.shape[0]} rewards for {n_steps} actions; the dataset is "
                        "malformed.")
    if not np.all(np.isfinite(rews)):
        raise UserError(f"{where} has NaN or inf rewards; re-record the dataset or drop that episode.")
    term = np.asarray(ep.terminations, dtype=bool).reshape(-1)
    if term.shape != (n_steps,):
        raise UserError(f"{where} has {term.shape[0]} termination flags for {n_steps} actions; the dataset "
                        "is malformed.")
    if term[:-1].any():
        raise UserError(f"{where} terminates at step {int(np.argmax(term))} before its last step; split such "
                        "episodes before saving.")
    subtasks = read_labels(where, ep.infos, n_steps)
    return Trajectory(obs=obs.astype(np.float32), acts=acts, rews=rews if rewards_recorded else None,
                      subtasks=subtasks, terminated=bool(term[-1]))
