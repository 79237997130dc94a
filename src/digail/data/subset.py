"""A subset of demonstrations: the first N episodes, every k-th transition (the few-demonstration regime of GAIL
and DAC: 1-4 trajectories, every 20th step)."""

from __future__ import annotations

import numpy as np

from digail.data.trajectory import Trajectory
from digail.errors import UserError


def subsample(traj: Trajectory, every: int, offset: int) -> Trajectory:
    """The transitions offset, offset + every, ... of `traj` as a shorter trajectory.

    Each kept transition keeps its own state and action (and reward and label); the observation after the last one
    is its own successor, so every (s_t, a_t) pair is one the expert really made. Consecutive rows are `every` steps
    apart in the original episode, which the VAE then reads as one step. The episode's `terminated` flag is kept.
    """
    idx = np.arange(offset, len(traj), every)
    obs = np.asarray(traj.obs)
    sub = None if traj.subtasks is None else np.asarray(traj.subtasks)[np.append(idx, idx[-1] + 1)]
    return Trajectory(obs=obs[np.append(idx, idx[-1] + 1)], acts=np.asarray(traj.acts)[idx],
                      rews=None if traj.rews is None else np.asarray(traj.rews)[idx], subtasks=sub,
                      terminated=traj.terminated)


def select_demos(trajs: list[Trajectory], episodes: int | None = None, every: int = 1,
                 seed: int = 0) -> list[Trajectory]:
    """The first `episodes` demonstrations (None: all), each subsampled to every `every`-th transition from a
    random offset in [0, every) per episode, drawn from `seed` (the same seed picks the same transitions in the
    VAE's pre-training and in the adversarial training)."""
    if episodes is not None:
        if episodes < 1:
            raise UserError(f"--demos-episodes must be at least 1, got {episodes}.")
        if episodes > len(trajs):
            raise UserError(f"--demos-episodes {episodes} asks for more episodes than the dataset's {len(trajs)}; "
                            "pass at most that many.")
        trajs = trajs[:episodes]
    if every < 1:
        raise UserError(f"--demos-subsample must be at least 1, got {every}.")
    if every == 1:
        return list(trajs)
    longest = max((len(t) for t in trajs), default=0)
    if every >= longest:
        raise UserError(f"--demos-subsample {every} is at least as long as every demonstration (the longest has "
                        f"{longest} transitions), so each would keep a single transition; pass at most "
                        f"{max(longest - 1, 1)}.")
    rng = np.random.default_rng(seed)
    offsets = rng.integers(every, size=len(trajs))
    return [subsample(t, every, int(min(o, len(t) - 1))) for t, o in zip(trajs, offsets, strict=True)]
