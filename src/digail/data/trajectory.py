"""The in-memory demonstration types: one episode (`Trajectory`) and a loaded dataset (`Dataset`)."""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import gymnasium as gym
import numpy as np

SUBTASK_KEY = "subtask"
"""Episode-info key holding the oracle sub-task labels (`info["subtask"]` at every step)."""


@dataclass(frozen=True)
class Trajectory:
    """One episode: `T` transitions, `T + 1` observations.

    Validation happens in `__post_init__`, so a `Trajectory` that exists is well-formed.
    """

    obs: np.ndarray
    """(T + 1, *obs_shape) float32 observations; row t is the state the t-th action was taken in, the last row
    is the state after the final action."""
    acts: np.ndarray
    """(T, *act_shape) actions: float32 for continuous spaces, int64 indices for discrete ones."""
    rews: np.ndarray | None = None
    """(T,) float32 environment rewards, or None when the source has none."""
    subtasks: np.ndarray | None = None
    """(T + 1,) int64 oracle sub-task labels aligned with `obs` (label at reset, then after each step), or None."""
    terminated: bool = False
    """True when the episode ended in a terminal state (no bootstrapping past it)."""

    def __post_init__(self) -> None:
        obs, acts = np.asarray(self.obs), np.asarray(self.acts)
        if obs.ndim < 1 or acts.ndim < 1:
            raise ValueError("obs and acts must be arrays with a leading time axis")
        if len(obs) != len(acts) + 1:
            raise ValueError(
                f"expected one more observation than actions, got {len(obs)} observations and {len(acts)} actions"
            )
        if len(acts) == 0:
            raise ValueError("a trajectory needs at least one transition")
        if not np.issubdtype(obs.dtype, np.number):
            raise ValueError(f"observations must be numeric, got dtype {obs.dtype}")
        if not np.all(np.isfinite(obs)):
            raise ValueError("observations contain NaN or inf values")
        if np.issubdtype(acts.dtype, np.floating) and not np.all(np.isfinite(acts)):
            raise ValueError("actions contain NaN or inf values")
        if not (np.issubdtype(acts.dtype, np.floating) or np.issubdtype(acts.dtype, np.integer)):
            raise ValueError(f"actions must be float or integer, got dtype {acts.dtype}")
        if self.rews is not None:
            rews = np.asarray(self.rews)
            if rews.shape != (len(acts),):
                raise ValueError(f"expected rews of shape ({len(acts)},), got {rews.shape}")
            if not np.all(np.isfinite(rews)):
                raise ValueError("rewards contain NaN or inf values")
        if self.subtasks is not None:
            sub = np.asarray(self.subtasks)
            if sub.shape != (len(obs),):
                raise ValueError(f"expected subtasks of shape ({len(obs)},) aligned with obs, got {sub.shape}")
            if not np.issubdtype(sub.dtype, np.integer):
                raise ValueError(f"subtask labels must be integers, got dtype {sub.dtype}")

    def __len__(self) -> int:
        """Number of transitions T."""
        return len(self.acts)

    @property
    def discrete(self) -> bool:
        """Whether the actions are integer indices."""
        return bool(np.issubdtype(np.asarray(self.acts).dtype, np.integer))


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
