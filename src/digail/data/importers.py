"""Demonstrations in the formats other tools write, read into `Trajectory` lists and written as Minari datasets.

The layouts (`FORMATS`), each a `.npz` file, an HDF5 file or a dict of arrays:

- `sb3`: rollouts as Stable-Baselines' `generate_expert_traj` and SB3's `RolloutBuffer` store them: `obs` and
  `actions` with one row per step, `episode_starts` (True where a row is the first of an episode; a 2-D
  `(steps, envs)` array holds one stream per env, as the rollout buffer does), optional `rewards` and `next_obs`.
- `imitation`: a list of imitation's `Trajectory` / `TrajectoryWithRew` saved as arrays: `obs` (each trajectory's
  T + 1 observations, one trajectory after another), `acts`, `indices` (where each trajectory's actions start,
  after the first: the cumulative lengths), `terminal` (one flag per trajectory), optional `rews`. The `infos`
  array imitation also writes holds pickled Python objects and is never read.
- `d4rl`: D4RL's flat transitions: `observations`, `actions`, `terminals` and/or `timeouts` (an episode ends after
  a step flagged by either: termination or time limit), optional `rewards` and `next_observations`.
- `arrays`: plain arrays with episode ends: `observations` (or `obs`), `actions` (or `acts`), `episode_ends` (one
  past each episode's last step: the cumulative lengths, the last equal to the number of steps), optional
  `rewards` and `terminated` (one flag per episode).
- `imitation-transitions`: imitation's flattened transitions saved with numpy (`obs`, `acts`, `next_obs`, `dones`;
  `digail.data.imitation_hf`).
- `imitation-dataset`: the HuggingFace datasets folder imitation >= 1.0 saves trajectories as
  (`digail.data.imitation_hf`).
- `robomimic`: a robomimic HDF5 file (`data/demo_<n>/obs/<key>`, `actions`, ...; `digail.data.robomimic`).
- `lerobot`: a LeRobot dataset folder (`meta/info.json`, Parquet frames below `data/`; `digail.data.lerobot`).

The state after an episode's last action: imitation stores it, D4RL and SB3 only with `next_observations` /
`next_obs`, plain arrays when `observations` has one row more per episode than the steps. Where a file does not
store it, that last action is dropped (a transition without its next state is no demonstration step) and the
episode is kept as truncated; `Imported.notes` says so. Pickled arrays are never loaded.
"""

from __future__ import annotations

import os
import re
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

import gymnasium as gym
import numpy as np

from digail.data.array_files import FILE_SUFFIXES
from digail.data.array_files import REQUIRED as _REQUIRED
from digail.data.array_files import Arrays as _Arrays
from digail.data.array_files import class_of as _class_of
from digail.data.array_files import open_arrays as _open
from digail.data.named_arrays import (
    _actions,
    _check_consistent,
    _read_arrays,
    _read_d4rl,
    _read_imitation,
    _read_sb3,
    _rows,
    _traj,
)
from digail.data.trajectory import Trajectory
from digail.errors import UserError

FORMATS = ("sb3", "imitation", "d4rl", "arrays", "imitation-transitions", "imitation-dataset", "robomimic", "lerobot")
"""the layouts `read_demonstrations` understands (see the module docstring)"""


@dataclass(frozen=True)
class Imported:
    """Demonstrations read from another tool's layout."""

    trajs: list[Trajectory]
    """the episodes, in stored order"""
    fmt: str
    """the layout they were read as (one of `FORMATS`)"""
    observation_space: gym.Space
    """their observation space: the environment's (`prepare_import` with an env) or the data's (`spaces_from_data`)"""
    action_space: gym.Space
    """their action space, likewise"""
    source: str | None = None
    """the file they were read from (None: a dict of arrays)"""
    env_id: str | None = None
    """the environment they were checked against (None: none; the spaces come from the data)"""
    notes: list[str] = field(default_factory=list)
    """what the reading had to give up, in sentences (e.g. last actions dropped for want of a next state)"""
    found: str = ""
    """what the layout's detection found, as a phrase (e.g. "a robomimic file (10 demonstrations ...)")"""
    episode_keys: list[str] = field(default_factory=list)
    """each episode's name in the source (robomimic's demo group, LeRobot's episode index; else its position),
    so that a segmentation can be written back to the episode it came from"""
    metadata: dict[str, Any] = field(default_factory=dict)
    """what the source says about itself, kept in the dataset (robomimic's `env_args`, the observation keys read)"""

    @property
    def num_steps(self) -> int:
        """Transitions over all episodes."""
        return sum(len(t) for t in self.trajs)


def is_import_source(text: str | os.PathLike[str]) -> bool:
    """Whether `text` names a file or folder `read_demonstrations` opens (rather than a Minari dataset folder or
    id): an `.npz` / HDF5 file, an imitation datasets folder or a LeRobot dataset folder."""
    from digail.data.imitation_hf import is_imitation_folder
    from digail.data.lerobot import is_lerobot

    path = Path(text)
    if path.is_dir():
        return is_imitation_folder(path) or is_lerobot(path)
    return path.suffix.lower() in FILE_SUFFIXES


# ------------------------------------------------------------------------------------------------ reading
def read_demonstrations(source: str | os.PathLike[str] | Mapping[str, Any], fmt: str = "auto",
                        obs_keys: Sequence[str] | None = None) -> Imported:
    """Read demonstrations from an `.npz` file, an HDF5 file, a folder or a dict of arrays in one of `FORMATS`.

    Args:
        source: the file or folder, or a dict of arrays (e.g. what D4RL's `env.get_dataset()` returns).
        fmt: one of `FORMATS`, or "auto" to tell the layout from the file (folder contents, HDF5 groups, array
            names).
        obs_keys: robomimic and LeRobot only: the observation keys to flatten and join, in this order (default:
            see `digail.data.robomimic` and `digail.data.lerobot`).

    Returns:
        The episodes as validated `Trajectory` objects (float32 observations; int64 actions when the file's are
        integers, else float32), with notes on anything given up.

    Raises:
        UserError: one sentence naming the file and the problem: missing arrays, lengths that do not add up,
            NaN or inf values, non-numeric or pickled arrays, episode marks that make no episode.
    """
    if fmt != "auto" and fmt not in FORMATS:
        raise UserError(f"unknown demonstration format {fmt!r}; choose auto or one of {', '.join(FORMATS)}.")
    if not isinstance(source, Mapping):
        from digail.data.formats import read_structured

        structured = read_structured(source, fmt, obs_keys)
        if structured is not None:
            trajs = trajectories_from_episodes(structured["source"], structured["episodes"])
            obs_space, act_space = spaces_from_data(trajs)
            return Imported(trajs=trajs, fmt=structured["fmt"], observation_space=obs_space, action_space=act_space,
                            source=structured["source"], notes=structured["notes"], found=structured["found"],
                            episode_keys=structured["episode_keys"], metadata=structured["metadata"])
    if obs_keys:
        what = "the given arrays" if isinstance(source, Mapping) else source
        raise UserError(f"--obs-keys applies to robomimic files and LeRobot datasets; {what} is read as named "
                        "arrays, drop it.")
    arrays, handle = _open(source)
    try:
        kind = _class_of(arrays) if fmt == "auto" else fmt
        for key in _REQUIRED[kind]:
            if not any(k in arrays for k in key.split("|")):
                raise UserError(f"{arrays.where} has no '{key.split('|')[0]}' array, which the {kind} layout needs; "
                                f"{arrays._hint()}.")
        if kind == "imitation-transitions":
            from digail.data.imitation_hf import read_imitation_transitions

            episodes, notes = read_imitation_transitions(arrays)
            trajs = trajectories_from_episodes(arrays.where, episodes)
        else:
            reader = {"sb3": _read_sb3, "imitation": _read_imitation, "d4rl": _read_d4rl, "arrays": _read_arrays}[kind]
            trajs, notes = reader(arrays)
        found = f"the {kind} layout ({', '.join(arrays.keys())})"
    finally:
        if handle is not None:
            handle.close()
    if not trajs:
        raise UserError(f"{arrays.where} holds no episode with at least one step and the state after it; import "
                        "longer episodes.")
    _check_consistent(arrays.where, trajs)
    obs_space, act_space = spaces_from_data(trajs)
    return Imported(trajs=trajs, fmt=kind, observation_space=obs_space, action_space=act_space,
                    source=None if isinstance(source, Mapping) else os.fspath(source), notes=notes, found=found,
                    episode_keys=[str(i) for i in range(len(trajs))])


def trajectories_from_episodes(where: str, episodes: Sequence[Mapping[str, Any]]) -> list[Trajectory]:
    """Validated episodes from the per-episode arrays the structured readers return (`digail.data.formats`).

    Each entry: `where` (the episode, for messages), `obs` (T + 1 rows), `acts` (T rows; `acts_name` names them in
    messages), optional `rews` (T), `terminated`, optional `subtasks` (T + 1 oracle labels). The checks are the
    named-array layouts': numbers only, finite, matching lengths, one observation shape.
    """
    trajs = []
    for ep in episodes:
        name, acts_name = ep["where"], ep.get("acts_name", "acts")
        arrays = _Arrays(name, {"obs": ep["obs"], acts_name: ep["acts"],
                                **({"rews": ep["rews"]} if ep.get("rews") is not None else {})})
        obs, acts, rews = arrays.get("obs"), arrays.get(acts_name), arrays.optional("rews")
        if obs.ndim < 1 or acts.ndim < 1 or len(obs) != len(acts) + 1:
            n_obs, n_acts = len(obs) if obs.ndim else 0, len(acts) if acts.ndim else 0
            raise UserError(f"{name} has {n_obs} observations for {n_acts} actions; an episode needs one more "
                            "observation (the state after its last action).")
        if rews is not None:
            _rows(name, "rewards", rews.reshape(-1), len(acts), "actions")
        traj = _traj(name, obs, _actions(name, acts_name, acts), rews, bool(ep.get("terminated", False)))
        if ep.get("subtasks") is not None:
            traj = replace(traj, subtasks=np.asarray(ep["subtasks"], dtype=np.int64))
        trajs.append(traj)
    if not trajs:
        raise UserError(f"{where} holds no episode; import a source with at least one.")
    _check_consistent(where, trajs)
    return trajs


def trajectories_from_objects(items: Sequence[Any]) -> list[Trajectory]:
    """Episodes from objects with imitation's trajectory fields: `obs` (T + 1 rows), `acts` (T rows), `terminal`,
    and `rews` where present (imitation's `Trajectory` / `TrajectoryWithRew`, or anything shaped like them).

    Raises:
        UserError: an object lacks a field, or its arrays are not a valid episode.
    """
    trajs = []
    for i, item in enumerate(items):
        where = f"trajectory {i}"
        try:
            fields = {"obs": item.obs, "acts": item.acts, "terminal": item.terminal}
        except AttributeError as exc:
            raise UserError(f"{where} has no {exc.name!r} field; pass objects with obs, acts and terminal (imitation's "
                            "trajectory types).") from None
        arrays = _Arrays(where, {**fields, "rews": getattr(item, "rews", None)} if getattr(item, "rews", None)
                         is not None else fields)
        obs, acts = arrays.get("obs"), arrays.get("acts")
        rews = arrays.optional("rews")
        if acts.ndim < 1 or obs.ndim < 1 or len(obs) != len(acts) + 1:
            raise UserError(f"{where} has {len(obs)} observations for {len(acts)} actions; a trajectory holds one "
                            "more observation than actions.")
        if rews is not None:
            _rows(where, "rews", rews, len(acts), "actions")
        trajs.append(_traj(where, obs, _actions(where, "acts", acts), rews, bool(fields["terminal"])))
    if not trajs:
        raise UserError("no trajectories were given; pass at least one.")
    _check_consistent("the trajectories", trajs)
    return trajs


# ------------------------------------------------------------------------------------------------ spaces
def spaces_from_data(trajs: Sequence[Trajectory]) -> tuple[gym.spaces.Box, gym.Space]:
    """Observation and action spaces the data itself implies, for demonstrations without an environment.

    Observations: an unbounded float32 Box of their shape. Actions: Discrete(largest index + 1) for integer
    actions (an action the demonstrations never take is not counted), else an unbounded float32 Box (the bounds are
    not in the data).
    """
    obs_space = gym.spaces.Box(-np.inf, np.inf, shape=trajs[0].obs.shape[1:], dtype=np.float32)
    if trajs[0].discrete:
        n = int(max(int(t.acts.max()) for t in trajs)) + 1
        return obs_space, gym.spaces.Discrete(n)
    return obs_space, gym.spaces.Box(-np.inf, np.inf, shape=trajs[0].acts.shape[1:], dtype=np.float32)


def fit_to_env(where: str, trajs: list[Trajectory], env_id: str) -> tuple[list[Trajectory], gym.Space, gym.Space]:
    """The episodes shaped as `env_id`'s spaces need (flat action rows reshaped, integer-valued float actions of a
    Discrete env as indices) and the env's spaces (Dict observations flattened); one sentence when they do not fit.
    """
    from digail.envs.registry import make_env

    env = make_env(env_id)
    try:
        obs_space, act_space = env.observation_space, env.action_space
    finally:
        env.close()
    if isinstance(obs_space, gym.spaces.Dict):
        obs_space = gym.spaces.flatten_space(obs_space)
    fix = f"import demonstrations recorded in {env_id}, or pass the --env they were recorded in"
    got = trajs[0].obs.shape[1:]
    if not isinstance(obs_space, gym.spaces.Box) or int(np.prod(got)) != int(np.prod(obs_space.shape)):
        raise UserError(f"{where} has observations of shape {got} but {env_id} has {obs_space}; {fix}.")
    out = []
    for t in trajs:
        acts = t.acts
        if isinstance(act_space, gym.spaces.Discrete):
            if not t.discrete:
                if acts.shape[1:] != (1,) or not np.all(acts == np.round(acts)):
                    raise UserError(f"{where} has continuous actions of shape {acts.shape[1:]} but {env_id} has "
                                    f"{act_space}; {fix}.")
                acts = acts[:, 0].astype(np.int64)
            acts = acts - int(act_space.start)
            if acts.min() < 0 or acts.max() >= act_space.n:
                raise UserError(f"{where} has actions outside {env_id}'s {act_space}; {fix}.")
        elif isinstance(act_space, gym.spaces.Box):
            if t.discrete or int(np.prod(acts.shape[1:])) != int(np.prod(act_space.shape)):
                raise UserError(f"{where} has {'integer' if t.discrete else 'float'} actions of shape "
                                f"{acts.shape[1:]} but {env_id} has {act_space}; {fix}.")
            acts = acts.reshape(len(acts), *act_space.shape)
        else:
            raise UserError(f"{env_id} has action space {act_space}; only Box and Discrete actions are supported.")
        out.append(Trajectory(obs=t.obs.reshape(len(t.obs), *obs_space.shape), acts=acts, rews=t.rews,
                              subtasks=t.subtasks, terminated=t.terminated))
    return out, obs_space, act_space


# ------------------------------------------------------------------------------------------------ writing
def default_import_id(source: str | os.PathLike[str] | None) -> str:
    """Minari id for imported demonstrations, from the file's name: `mine.npz` -> `imported/mine-v0`."""
    stem = Path(source).stem if source is not None else "demos"
    name = re.sub(r"[^a-z0-9_-]", "", stem.lower().replace(".", "-").replace(" ", "-")) or "demos"
    name = re.sub(r"-v\d+$", "", name) or "demos"
    return f"imported/{name}-v0"


def prepare_import(source: str | os.PathLike[str] | Mapping[str, Any], *, env_id: str | None = None,
                   fmt: str = "auto", obs_keys: Sequence[str] | None = None) -> Imported:
    """`read_demonstrations`, then fitted to `env_id`'s spaces when one is given (`fit_to_env`): everything that can
    go wrong with the data, checked before anything is written."""
    imported = read_demonstrations(source, fmt, obs_keys)
    if not env_id:
        return imported
    trajs, obs_space, act_space = fit_to_env(imported.source or "the given arrays", imported.trajs, env_id)
    return replace(imported, trajs=trajs, observation_space=obs_space, action_space=act_space, env_id=env_id)


def write_imported(imported: Imported, out: str | os.PathLike[str], *, dataset_id: str | None = None,
                   force: bool = False) -> Path:
    """Write demonstrations from `prepare_import` as a Minari dataset folder at `out` (atomically); returns it."""
    from digail.data.minari_write import write_dataset

    trajs = imported.trajs
    record = {"imported_from": None if imported.source is None else str(Path(imported.source).resolve()),
              "format": imported.fmt, "notes": imported.notes, "episodes": len(trajs),
              "steps": imported.num_steps, "found": imported.found, "episode_keys": imported.episode_keys,
              "source_metadata": imported.metadata}
    env_words = f" recorded in {imported.env_id}" if imported.env_id else ""
    description = f"{len(trajs)} demonstrations{env_words} imported by digail from the {imported.fmt} layout."
    return write_dataset(trajs, out, imported.env_id, dataset_id or default_import_id(imported.source),
                         force=force, description=description, algorithm_name=None,
                         observation_space=imported.observation_space, action_space=imported.action_space,
                         extra_metadata=record)


def import_demonstrations(source: str | os.PathLike[str] | Mapping[str, Any], out: str | os.PathLike[str] | None
                          = None, *, env_id: str | None = None, fmt: str = "auto", dataset_id: str | None = None,
                          force: bool = False, obs_keys: Sequence[str] | None = None) -> tuple[Path, Imported]:
    """Read demonstrations in another tool's layout and write them as a Minari dataset; returns its folder.

    Args:
        source: an `.npz` or HDF5 file, or a dict of arrays (see `read_demonstrations`).
        out: the dataset folder (default: the Minari root, `$MINARI_DATASETS_PATH` or `~/.minari/datasets`, then
            the dataset id, so that the id resolves there).
        env_id: the environment the data was recorded in: checked against its spaces, and stored so that training
            and evaluation can make it. None: the spaces come from the data (`spaces_from_data`) and the dataset
            names no environment (it can be pre-trained on and segmented, not trained in an env).
        fmt: one of `FORMATS`, or "auto".
        dataset_id: the Minari id stored in the metadata (default: `default_import_id`).
        force: replace an existing dataset folder.
        obs_keys: robomimic and LeRobot only: the observation keys to read (see `read_demonstrations`).

    Returns:
        The dataset folder and what was read (`Imported`, with its notes).

    Raises:
        UserError: a malformed source (see `read_demonstrations`), data that does not fit `env_id`, an unknown
            env id, an existing `out` without `force`.
    """
    from minari.dataset.minari_dataset import parse_dataset_id

    from digail.data.minari_io import minari_root
    from digail.fsio import check_clear_of, check_new_dir

    dataset_id = dataset_id or default_import_id(None if isinstance(source, Mapping) else os.fspath(source))
    try:  # before the id becomes a folder below the Minari root
        parse_dataset_id(dataset_id)
    except ValueError as exc:
        raise UserError(f"invalid Minari dataset id {dataset_id!r}; use the form namespace/name-v0.") from exc
    path = Path(out) if out is not None else minari_root() / dataset_id
    if not isinstance(source, Mapping):  # the dataset never replaces, or lands inside, what it is read from
        check_clear_of(path, [(source, "the input")])
    check_new_dir(path, force)  # before reading a possibly large file
    imported = prepare_import(source, env_id=env_id, fmt=fmt, obs_keys=obs_keys)
    return write_imported(imported, path, dataset_id=dataset_id, force=force), imported
