"""Checks that demonstrations fit an environment: actions, labels, spaces, and the arrays the VAE trains on.

Every failure is one `UserError` sentence naming the episode (`where`) and the fix.
"""

from __future__ import annotations

import json
from collections.abc import Sequence
from typing import Any

import gymnasium as gym
import numpy as np

from digail.data.trajectory import SUBTASK_KEY, Dataset, Trajectory
from digail.envs.registry import env_spaces, make_env
from digail.errors import UserError
from digail.nets.policy import ActionSpec


def check_actions(where: str, acts: np.ndarray, space: gym.Space) -> np.ndarray:
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


def read_labels(where: str, infos: Any, n_steps: int) -> np.ndarray | None:
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


def _spaces(env_id: str, env_kwargs: dict[str, Any]) -> tuple[gym.Space, gym.Space]:
    """The env's observation and action spaces: the registry's (`env_spaces`, made once per process) for the
    default options, else from an env made with `env_kwargs`."""
    if not env_kwargs:
        return env_spaces(env_id)
    env = make_env(env_id, **env_kwargs)
    try:
        return env.observation_space, env.action_space
    finally:
        env.close()


def check_matches_env(dataset: Dataset, env_id: str, **env_kwargs: Any) -> None:
    """Check that `dataset` can train a policy for `env_id`: same observation shape, same action space.

    Dict observation spaces of the env are compared in their flattened form (what `load_dataset` produces).

    Raises:
        UserError: naming both spaces and the fix when they differ, or when `env_id` is unknown.
    """
    try:
        env_obs, env_act = _spaces(env_id, env_kwargs)
    except UserError as exc:
        if env_id != dataset.env_id:
            raise
        raise UserError(f"dataset {dataset.dataset_id} was recorded in {env_id}, which {_cannot_make(exc)}; training "
                        "and evaluation need that environment (install what registers it), while `digail pretrain` "
                        "and `digail segment` work from the dataset alone.") from exc
    if isinstance(env_obs, gym.spaces.Dict):
        env_obs = gym.spaces.flatten_space(env_obs)
    recorded = f" (recorded in {dataset.env_id})" if dataset.env_id else ""
    fix = "pass a dataset recorded in this environment or choose the matching --env"
    if not isinstance(env_obs, gym.spaces.Box) or env_obs.shape != dataset.observation_space.shape:
        raise UserError(f"dataset {dataset.dataset_id}{recorded} has observations of shape "
                        f"{dataset.observation_space.shape} but {env_id} has {env_obs}; {fix}.")
    if not same_action_space(dataset.action_space, env_act):
        raise UserError(f"dataset {dataset.dataset_id}{recorded} has action space {dataset.action_space} but "
                        f"{env_id} has {env_act}; {fix}.")


def _cannot_make(exc: UserError) -> str:
    """Why an env cannot be made, from `make_env`'s sentence: its first clause (no list of known ids), or how to
    allow it when a data file defines it in a module no one named."""
    hint = str(exc).split("; ", 1)[1].rstrip(".") if "; a data file defines it" in str(exc) else ""
    return "cannot be made here (" + (hint or str(exc).split(";")[0].rstrip(".")) + ")"


def check_dataset_env(dataset: Dataset) -> str | None:
    """Check a dataset against the environment its metadata names, where that environment can be made.

    Returns:
        None when the dataset fits its environment; a sentence saying what will not work when the dataset names
        no environment or one that cannot be made here (its spaces then come from the dataset: pre-training and
        segmentation work, training and evaluation do not).

    Raises:
        UserError: the environment can be made and its spaces do not fit the data (`check_matches_env`).
    """
    after = ("the VAE takes its spaces from the dataset, so pre-training and `digail segment` work, but `digail "
             "train`, `evaluate` and `run` need an environment")
    if dataset.env_id is None:
        return f"dataset {dataset.dataset_id} names no environment; {after} (pass it to `digail train --env`)."
    kwargs = recorded_env_kwargs(dataset)
    try:
        make_env(dataset.env_id, **kwargs).close()
    except UserError as exc:
        return f"dataset {dataset.dataset_id} was recorded in {dataset.env_id}, which {_cannot_make(exc)}; {after}."
    check_matches_env(dataset, dataset.env_id, **kwargs)
    return None


def recorded_env_kwargs(dataset: Dataset) -> dict[str, Any]:
    """The keyword arguments the dataset's environment was made with, from Minari's stored env spec (a waypoint
    course on a grid has discrete actions where the same env id's default has continuous ones); {} when the spec
    holds none."""
    spec = (getattr(dataset, "metadata", None) or {}).get("env_spec")
    try:
        kwargs = (json.loads(spec) if isinstance(spec, str) else spec or {}).get("kwargs") or {}
    except (ValueError, AttributeError):
        return {}
    return dict(kwargs) if isinstance(kwargs, dict) else {}


def same_action_space(a: gym.Space, b: gym.Space) -> bool:
    if isinstance(a, gym.spaces.Discrete) and isinstance(b, gym.spaces.Discrete):
        return int(a.n) == int(b.n)
    if isinstance(a, gym.spaces.Box) and isinstance(b, gym.spaces.Box):
        return a.shape == b.shape
    return False


def validate_for_space(where: str, traj: Trajectory, obs_space: gym.Space, act_space: gym.Space) -> None:
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


def check_demos(trajs: Sequence[Trajectory], action_spec: ActionSpec | None = None) -> tuple[int, ActionSpec]:
    """Validate a list of demonstrations for the model; return (obs_dim, action spec).

    Raises:
        UserError: no demonstrations, or inconsistent observation / action shapes or types.
    """
    if len(trajs) == 0:
        raise UserError("no demonstrations were given; pass a dataset with at least one episode.")
    obs_dims = {int(np.prod(np.shape(t.obs)[1:], dtype=np.int64)) for t in trajs}
    if len(obs_dims) != 1:
        raise UserError(f"demonstrations have different observation sizes {sorted(obs_dims)}; use one environment.")
    kinds = {t.discrete for t in trajs}
    if len(kinds) != 1:
        raise UserError("demonstrations mix discrete and continuous actions; use one environment.")
    if action_spec is None:
        acts = np.concatenate([np.asarray(t.acts).reshape(len(t), -1) for t in trajs])
        action_spec = ActionSpec.from_actions(acts[:, 0] if trajs[0].discrete else acts)
    if action_spec.discrete != trajs[0].discrete:
        kind = "discrete" if action_spec.discrete else "continuous"
        raise UserError(f"the action space is {kind} but the demonstrations' actions are not; check the dataset.")
    for t in trajs:
        acts = np.asarray(t.acts)
        if action_spec.discrete:
            if acts.reshape(len(t), -1).shape[1] != 1 or acts.min() < 0 or acts.max() >= action_spec.dim:
                raise UserError(f"discrete actions must be indices in [0, {action_spec.dim}); check the dataset.")
        elif acts.reshape(len(t), -1).shape[1] != action_spec.dim:
            raise UserError(f"expected {action_spec.dim}-dimensional actions, got shape {acts.shape[1:]}.")
    return obs_dims.pop(), action_spec
