"""The named-array layouts of `digail.data.importers` (`sb3`, `imitation`, `d4rl`, `arrays`; its module docstring
describes each): one reader per layout, and the row, action and episode checks every importer shares. The
importers module keeps what dispatches to them, the spaces and the writing.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from digail.data.array_files import Arrays as _Arrays
from digail.data.trajectory import Trajectory
from digail.errors import UserError
from digail.utils import one_line


def _optional_rows(where: str, rews: np.ndarray | None, next_obs: np.ndarray | None, next_key: str,
                   obs: np.ndarray, obs_key: str, n: int, by: str) -> None:
    """The optional rewards and next observations: one row per step (`_rows`), next observations shaped as `obs`."""
    if rews is not None:
        _rows(where, "rewards", rews, n, by)
    if next_obs is not None:
        _rows(where, next_key, next_obs, n, by)
        if next_obs.shape[1:] != obs.shape[1:]:
            raise UserError(f"{where} has '{next_key}' of shape {next_obs.shape[1:]} per step but '{obs_key}' of "
                            f"{obs.shape[1:]}; they must match.")


def _rows(where: str, name: str, arr: np.ndarray, n: int, what: str) -> None:
    if arr.ndim < 1 or len(arr) != n:
        got = len(arr) if arr.ndim >= 1 else "a scalar"
        raise UserError(f"{where} has {got} rows of '{name}' but {n} {what}; the arrays must have matching "
                        "lengths.")


def _actions(where: str, name: str, acts: np.ndarray) -> np.ndarray:
    """int64 indices (integer actions, a trailing axis of 1 dropped as SB3 stores Discrete) or float32 rows."""
    if np.issubdtype(acts.dtype, np.integer) or acts.dtype == np.bool_:
        if acts.ndim == 2 and acts.shape[1] == 1:
            acts = acts[:, 0]
        if acts.ndim != 1:
            raise UserError(f"{where} has integer '{name}' of shape {acts.shape[1:]} per step; discrete actions must "
                            "be one index per step (save continuous actions as floats).")
        if acts.size and acts.min() < 0:
            raise UserError(f"{where} has negative integer '{name}'; discrete actions must be indices 0..n-1.")
        return acts.astype(np.int64)
    acts = acts.astype(np.float32)
    return acts[:, None] if acts.ndim == 1 else acts


def _traj(where: str, obs: np.ndarray, acts: np.ndarray, rews: np.ndarray | None, terminated: bool) -> Trajectory:
    try:
        return Trajectory(obs=obs.astype(np.float32), acts=acts,
                          rews=None if rews is None else rews.astype(np.float32).reshape(-1), terminated=terminated)
    except ValueError as exc:  # the checks above should leave nothing for these; named all the same
        raise UserError(f"{where} gives an invalid episode ({one_line(exc)}).") from exc


def _split_rows(where: str, obs: np.ndarray, acts: np.ndarray, rews: np.ndarray | None, next_obs: np.ndarray | None,
                bounds: Sequence[tuple[int, int]], terminal: Sequence[bool]) -> tuple[list[Trajectory], int]:
    """Episodes of rows [a, b) with one observation per step: the last row's next state from `next_obs`, else
    that last step dropped (returned: how many were)."""
    trajs: list[Trajectory] = []
    dropped = 0
    for (a, b), term in zip(bounds, terminal, strict=True):
        if next_obs is not None:
            trajs.append(_traj(where, np.concatenate([obs[a:b], next_obs[b - 1:b]]), acts[a:b],
                               None if rews is None else rews[a:b], bool(term)))
            continue
        dropped += 1
        if b - a >= 2:
            trajs.append(_traj(where, obs[a:b], acts[a:b - 1], None if rews is None else rews[a:b - 1], False))
    return trajs, dropped


def _dropped_note(dropped: int, next_name: str) -> list[str]:
    if not dropped:
        return []
    return [f"the file stores no state after an episode's last action (no '{next_name}'), so the last action of "
            f"each of {dropped} episodes was dropped and the episodes kept as truncated"]


def _read_sb3(arrays: _Arrays) -> tuple[list[Trajectory], list[str]]:
    where = arrays.where
    starts = arrays.get("episode_starts", kind="flag")
    obs, acts = arrays.get("obs"), arrays.get("actions")
    rews, next_obs = arrays.optional("rewards"), arrays.optional("next_obs")
    if starts.ndim == 2:  # SB3's rollout buffer: (steps, envs), one stream per env column
        n_steps, n_envs = starts.shape
        for name, arr in (("obs", obs), ("actions", acts), ("rewards", rews), ("next_obs", next_obs)):
            if arr is not None and arr.shape[:2] != (n_steps, n_envs):
                raise UserError(f"{where} has '{name}' of shape {arr.shape} but 'episode_starts' of shape "
                                f"{starts.shape}; a (steps, envs) buffer needs both leading axes in every array.")

        def streams(arr: np.ndarray) -> np.ndarray:
            return np.concatenate([arr[:, j] for j in range(n_envs)])

        obs, acts = streams(obs), streams(acts)
        rews = None if rews is None else streams(rews)
        next_obs = None if next_obs is None else streams(next_obs)
        starts = starts.T.copy()
        starts[:, 0] = True  # each env's column is its own stream
        starts = starts.reshape(-1)
    elif starts.ndim != 1:
        raise UserError(f"{where} has 'episode_starts' of shape {starts.shape}; it must be one flag per step, or "
                        "(steps, envs) as in SB3's rollout buffer.")
    n = len(starts)
    _rows(where, "obs", obs, n, "episode_starts flags")
    _rows(where, "actions", acts, n, "episode_starts flags")
    _optional_rows(where, rews, next_obs, "next_obs", obs, "obs", n, "episode_starts flags")
    acts = _actions(where, "actions", acts)
    first = np.flatnonzero(starts).tolist()
    if not first or first[0] != 0:
        first = [0, *first]  # rows before the first flagged start: the tail of an episode begun earlier
    bounds = list(zip(first, [*first[1:], n], strict=True))
    trajs, dropped = _split_rows(where, obs, acts, rews, next_obs, bounds, [False] * len(bounds))
    return trajs, _dropped_note(dropped, "next_obs")


def _read_imitation(arrays: _Arrays) -> tuple[list[Trajectory], list[str]]:
    where = arrays.where
    obs, acts = arrays.get("obs"), arrays.get("acts")
    indices, terminal = arrays.get("indices", kind="index"), arrays.get("terminal", kind="flag")
    rews = arrays.optional("rews")
    if indices.ndim != 1:
        raise UserError(f"{where} has 'indices' of shape {indices.shape}; it must be a 1-D array of split points.")
    n_trajs = len(indices) + 1
    if terminal.shape != (n_trajs,):
        raise UserError(f"{where} has {terminal.size} 'terminal' flags for {n_trajs} trajectories (one more than "
                        "'indices'); the arrays do not fit together.")
    if acts.ndim < 1 or len(obs) != len(acts) + n_trajs:
        raise UserError(f"{where} has {len(obs)} observations for {len(acts)} actions in {n_trajs} trajectories; "
                        "imitation stores one more observation than actions per trajectory.")
    if rews is not None:
        _rows(where, "rews", rews, len(acts), "actions")
    if np.any(np.diff(np.concatenate([[0], indices, [len(acts)]])) <= 0):
        raise UserError(f"{where} has 'indices' that are not strictly increasing within 1..{len(acts) - 1}; every "
                        "trajectory needs at least one action.")
    acts = _actions(where, "acts", acts)
    act_splits = np.split(acts, indices)
    obs_splits = np.split(obs, indices + np.arange(1, n_trajs))
    rew_splits = np.split(rews, indices) if rews is not None else [None] * n_trajs
    trajs = [_traj(where, o, a, r, bool(t))
             for o, a, r, t in zip(obs_splits, act_splits, rew_splits, terminal, strict=True)]
    return trajs, []


def _read_d4rl(arrays: _Arrays) -> tuple[list[Trajectory], list[str]]:
    where = arrays.where
    obs, acts = arrays.get("observations"), arrays.get("actions")
    n = len(obs) if obs.ndim >= 1 else 0
    _rows(where, "actions", acts, n, "observations")
    terminals, timeouts = arrays.optional("terminals", "flag"), arrays.optional("timeouts", "flag")
    if terminals is None and timeouts is None:
        raise UserError(f"{where} has neither 'terminals' nor 'timeouts', so its episodes cannot be told apart; add "
                        "the flags that end each episode.")
    for name, flags in (("terminals", terminals), ("timeouts", timeouts)):
        if flags is not None and flags.ndim != 1:
            raise UserError(f"{where} has '{name}' of shape {flags.shape}; it must be one flag per step, a 1-D "
                            "array as long as 'observations'.")
    terminals = np.zeros(n, bool) if terminals is None else terminals
    timeouts = np.zeros(n, bool) if timeouts is None else timeouts
    _rows(where, "terminals", terminals, n, "observations")
    _rows(where, "timeouts", timeouts, n, "observations")
    rews, next_obs = arrays.optional("rewards"), arrays.optional("next_observations")
    _optional_rows(where, rews, next_obs, "next_observations", obs, "observations", n, "observations")
    acts = _actions(where, "actions", acts)
    ends = (np.flatnonzero(terminals | timeouts) + 1).tolist()
    notes = []
    if not ends or ends[-1] != n:
        notes.append(f"the last {n - (ends[-1] if ends else 0)} steps end neither in a terminal nor a timeout and "
                     "were kept as a truncated episode")
        ends.append(n)
    starts = [0, *ends[:-1]]
    bounds = list(zip(starts, ends, strict=True))
    terminal = [bool(terminals[b - 1]) for _, b in bounds]
    trajs, dropped = _split_rows(where, obs, acts, rews, next_obs, bounds, terminal)
    return trajs, _dropped_note(dropped, "next_observations") + notes


def _read_arrays(arrays: _Arrays) -> tuple[list[Trajectory], list[str]]:
    where = arrays.where
    obs, acts = arrays.first("observations", "obs"), arrays.first("actions", "acts")
    ends = arrays.get("episode_ends", kind="index")
    rews = arrays.optional("rewards")
    terminated = arrays.optional("terminated", "flag")
    n = len(acts) if acts.ndim >= 1 else 0
    if ends.ndim != 1 or len(ends) == 0 or np.any(np.diff(np.concatenate([[0], ends])) <= 0) or ends[-1] != n:
        raise UserError(f"{where} has 'episode_ends' that are not strictly increasing positive step counts ending at "
                        f"the number of actions ({n}); each entry is one past an episode's last step.")
    if rews is not None:
        _rows(where, "rewards", rews, n, "actions")
    if terminated is not None and terminated.shape != ends.shape:
        raise UserError(f"{where} has {terminated.size} 'terminated' flags for {len(ends)} episodes; give one per "
                        "episode.")
    terminal = [False] * len(ends) if terminated is None else terminated.tolist()
    acts = _actions(where, "actions", acts)
    starts = np.concatenate([[0], ends[:-1]])
    if len(obs) == n + len(ends):  # each episode's T + 1 observations
        trajs = [_traj(where, obs[a + i:b + i + 1], acts[a:b], None if rews is None else rews[a:b], bool(t))
                 for i, (a, b, t) in enumerate(zip(starts, ends, terminal, strict=True))]
        return trajs, []
    if len(obs) != n:
        raise UserError(f"{where} has {len(obs)} observations for {n} actions in {len(ends)} episodes; give one "
                        "observation per action, or one more per episode (the state after its last action).")
    trajs, dropped = _split_rows(where, obs, acts, rews, None, list(zip(starts, ends, strict=True)), terminal)
    return trajs, [f"'observations' has one row per action, so the state after each episode's last action is "
                   f"missing: the last action of each of {dropped} episodes was dropped and the episodes kept as "
                   "truncated"]


def _check_consistent(where: str, trajs: Sequence[Trajectory]) -> None:
    shapes = {t.obs.shape[1:] for t in trajs}
    if len(shapes) != 1:
        raise UserError(f"{where} has episodes with observations of shapes {sorted(shapes)}; all episodes must "
                        "come from one environment.")
