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

import contextlib
import json
import os
import shutil
import warnings
from collections.abc import Callable, Iterator, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import gymnasium as gym
import numpy as np

from digail.data.trajectory import Trajectory
from digail.envs.registry import make_env
from digail.errors import UserError
from digail.utils import atomic_dir, json_default, one_line

SHIPPED_ROOT = Path(__file__).resolve().parent.parent / "datasets"
"""Minari root of the datasets shipped inside the package (ids resolve here first)."""

SUBTASK_KEY = "subtask"
"""Episode-info key holding the oracle sub-task labels."""

ObsHook = Callable[[Any, gym.Space], np.ndarray]
"""Turns one episode's stored observations (array, dict of arrays, ...) into a `(T + 1, d)` array."""


@dataclass(frozen=True)
class Dataset:
    """Demonstrations read from a Minari dataset, validated against its own spaces."""

    trajs: list[Trajectory]
    """episodes in stored order"""
    env_id: str | None
    """id of the environment the data was collected in (from the stored env spec), or None"""
    observation_space: gym.Space
    """observation space of `trajs` (after any flattening hook)"""
    action_space: gym.Space
    """action space of the data (Box: float32 actions, Discrete: int64 indices)"""
    dataset_id: str
    """Minari dataset id recorded in the metadata"""
    path: Path
    """the dataset folder (the one holding `data/`)"""
    metadata: dict[str, Any] = field(default_factory=dict, repr=False)
    """raw `metadata.json` content (includes digail's own record under the key "digail" when we wrote it)"""

    @property
    def has_labels(self) -> bool:
        """Whether every episode carries oracle sub-task labels."""
        return all(t.subtasks is not None for t in self.trajs)

    @property
    def num_steps(self) -> int:
        """Total transitions over all episodes."""
        return sum(len(t) for t in self.trajs)


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
    if not Path(text).is_absolute():
        candidates += [SHIPPED_ROOT / text, minari_root() / text]
    for folder in candidates:
        data = _data_dir(folder)
        if data is not None:
            return data.parent
    raise UserError(_missing_message(text))


def _read_metadata(data: Path) -> dict[str, Any]:
    try:
        with open(data / "metadata.json") as f:
            metadata = json.load(f)
    except (OSError, ValueError) as exc:
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
    acts = _check_actions(where, acts, act_space)
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
    subtasks = _labels(where, ep.infos, n_steps)
    return Trajectory(obs=obs.astype(np.float32), acts=acts, rews=rews if rewards_recorded else None,
                      subtasks=subtasks, terminated=bool(term[-1]))


def _check_actions(where: str, acts: np.ndarray, space: gym.Space) -> np.ndarray:
    if isinstance(space, gym.spaces.Discrete):
        if acts.ndim == 2 and acts.shape[1] == 1:
            acts = acts[:, 0]
        if acts.ndim != 1:
            raise UserError(f"{where} has actions of shape {acts.shape[1:]} but the action space is {space}; "
                            "the dataset is malformed.")
        if not np.issubdtype(acts.dtype, np.integer):
            raise UserError(f"{where} has {acts.dtype} actions but the action space {space} needs integers; "
                            "the dataset is malformed.")
        idx = acts.astype(np.int64) - int(space.start)  # indices 0..n-1, whatever the space's start
        if idx.min() < 0 or idx.max() >= space.n:
            raise UserError(f"{where} has actions outside {space}; the dataset is malformed.")
        return idx
    assert isinstance(space, gym.spaces.Box)
    if acts.shape[1:] != space.shape:
        raise UserError(f"{where} has actions of shape {acts.shape[1:]} but the action space has shape "
                        f"{space.shape}; the dataset is malformed.")
    if not np.issubdtype(acts.dtype, np.number):
        raise UserError(f"{where} has non-numeric actions (dtype {acts.dtype}); the dataset is malformed.")
    if not np.all(np.isfinite(acts)):
        raise UserError(f"{where} has NaN or inf values in its actions; re-record the dataset or drop that "
                        "episode.")
    return acts.astype(np.float32)


def _labels(where: str, infos: Any, n_steps: int) -> np.ndarray | None:
    if not isinstance(infos, dict) or SUBTASK_KEY not in infos:
        return None
    labels = np.asarray(infos[SUBTASK_KEY])
    if labels.shape != (n_steps + 1,):
        raise UserError(f"{where} has '{SUBTASK_KEY}' labels of shape {labels.shape}, expected "
                        f"({n_steps + 1},) (one at reset and one after each step); the dataset is malformed.")
    if not np.issubdtype(labels.dtype, np.integer):
        raise UserError(f"{where} has '{SUBTASK_KEY}' labels of dtype {labels.dtype}, expected integers; the "
                        "dataset is malformed.")
    return labels.astype(np.int64)


def check_matches_env(dataset: Dataset, env_id: str, **env_kwargs: Any) -> None:
    """Check that `dataset` can train a policy for `env_id`: same observation shape, same action space.

    Dict observation spaces of the env are compared in their flattened form (what `load_dataset` produces).

    Raises:
        UserError: naming both spaces and the fix when they differ, or when `env_id` is unknown.
    """
    env = make_env(env_id, **env_kwargs)
    try:
        env_obs, env_act = env.observation_space, env.action_space
    finally:
        env.close()
    if isinstance(env_obs, gym.spaces.Dict):
        env_obs = gym.spaces.flatten_space(env_obs)
    recorded = f" (recorded in {dataset.env_id})" if dataset.env_id else ""
    fix = "pass a dataset recorded in this environment or choose the matching --env"
    if not isinstance(env_obs, gym.spaces.Box) or env_obs.shape != dataset.observation_space.shape:
        raise UserError(f"dataset {dataset.dataset_id}{recorded} has observations of shape "
                        f"{dataset.observation_space.shape} but {env_id} has {env_obs}; {fix}.")
    if not _same_action_space(dataset.action_space, env_act):
        raise UserError(f"dataset {dataset.dataset_id}{recorded} has action space {dataset.action_space} but "
                        f"{env_id} has {env_act}; {fix}.")


def _same_action_space(a: gym.Space, b: gym.Space) -> bool:
    if isinstance(a, gym.spaces.Discrete) and isinstance(b, gym.spaces.Discrete):
        return int(a.n) == int(b.n)
    if isinstance(a, gym.spaces.Box) and isinstance(b, gym.spaces.Box):
        return a.shape == b.shape
    return False


# ------------------------------------------------------------------------------------------------ writing
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


def _validate_for_space(where: str, traj: Trajectory, obs_space: gym.Space, act_space: gym.Space) -> None:
    if not isinstance(obs_space, gym.spaces.Box):
        raise UserError(f"cannot write observations for space {obs_space}; flatten them first (Box only).")
    if traj.obs.shape[1:] != obs_space.shape:
        raise UserError(f"{where} has observations of shape {traj.obs.shape[1:]} but the environment's "
                        f"observation space has shape {obs_space.shape}.")
    if isinstance(act_space, gym.spaces.Discrete):
        if not traj.discrete or traj.acts.ndim != 1:
            raise UserError(f"{where} has {traj.acts.dtype} actions of shape {traj.acts.shape[1:]} but the "
                            f"action space {act_space} needs integer indices.")
        if traj.acts.min() < 0 or traj.acts.max() >= act_space.n:
            raise UserError(f"{where} has actions outside 0..{act_space.n - 1}.")
    elif isinstance(act_space, gym.spaces.Box):
        if traj.discrete or traj.acts.shape[1:] != act_space.shape:
            raise UserError(f"{where} has {traj.acts.dtype} actions of shape {traj.acts.shape[1:]} but the "
                            f"action space is {act_space}.")
    else:
        raise UserError(f"action space {act_space} is not supported; only Box and Discrete.")


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


def write_dataset(trajs: Sequence[Trajectory], path: str | os.PathLike[str], env_id: str, dataset_id: str, *,
                  force: bool = False, seeds: Sequence[int] | None = None, author: str | None = "digail",
                  description: str | None = None, algorithm_name: str | None = None,
                  observation_space: gym.Space | None = None, action_space: gym.Space | None = None,
                  extra_metadata: dict[str, Any] | None = None, compact: bool = True) -> Path:
    """Write trajectories as a Minari dataset folder at `path`, atomically.

    Everything is written into a temporary sibling folder that is renamed to `path` only on success: on any
    error nothing is left at `path` (an existing folder is replaced only with `force`, and only at the end).

    Args:
        trajs: the episodes; labels (if any) go to the episode infos under "subtask" (T + 1 entries).
        path: the dataset folder to create (it will hold `data/metadata.json` and `data/main_data.hdf5`).
        env_id: the environment the data comes from; its spec (id, entry point, kwargs, time limit) and spaces
            are stored so readers can recreate the env and check a dataset against one.
        dataset_id: Minari id stored in the metadata, e.g. "digail/circleworld/expert-v0".
        force: replace an existing folder at `path`.
        seeds: reset seed of each episode, stored per episode (Minari's `seed` attribute).
        author, description, algorithm_name: Minari metadata.
        observation_space, action_space: override the env's spaces (e.g. a flattened dict observation space).
        extra_metadata: JSON-serialisable record stored under the metadata key "digail" (digail adds
            `rewards_recorded`).
        compact: rewrite Minari's chunked HDF5 file with contiguous arrays (about 4x smaller for short
            episodes; see `_compact_hdf5`).

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
    env = make_env(env_id)
    try:
        spec = env.spec
        obs_space = observation_space or env.observation_space
        act_space = action_space or env.action_space
    finally:
        env.close()
    for i, traj in enumerate(trajs):
        _validate_for_space(f"episode {i}", traj, obs_space, act_space)
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
        tmp.chmod(0o777 & ~_umask())  # mkdtemp makes it private; give it the permissions of a plain mkdir
    return path


def _umask() -> int:
    mask = os.umask(0)
    os.umask(mask)
    return mask


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
