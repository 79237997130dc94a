"""The interface between the adversarial trainer and a policy learner.

The trainer (`digail.algos.gail.GAIL`, extended by `DirectedInfoGAIL`) owns what every learner shares: the
demonstrations, the imitation reward (`digail.algos.rewards`: D and its update by default), the macro-policy's
codes (q frozen) and the bonus: r = the imitation reward + lambda_1 * log q (`with_bonus`). A learner (PPO, SAC)
owns how the policy pi(a | s, c) is trained: it steps the envs through the trainer's hooks, keeps its own networks,
optimisers and buffers, and updates pi. It sees the trainer only through `Host`, the typed list of what a learner
may use, and the trainer sees a learner only through `Learner`.

Adding a learner is one module in `digail.algos.learners` with a class that satisfies `Learner` (constructed from a
`Host`) and one `LearnerEntry` in `digail.algos.learners.LEARNERS`; its settings are a dataclass field of
`TrainConfig` (as `ppo` and `sac` are) and its name a value of `TrainConfig.learner`.
"""

from __future__ import annotations

from collections.abc import Callable
from contextlib import AbstractContextManager
from dataclasses import dataclass
from typing import Any, Protocol

import numpy as np
import torch

from digail.algos.expert_data import ExpertData
from digail.algos.rewards.base import Reward
from digail.algos.rollout import RolloutState
from digail.config import TrainConfig
from digail.envs.vector import VectorEnv
from digail.nets.vae import HierarchicalPolicy


class Host(Protocol):
    """What a learner may use of its trainer (all of it public; nothing else of the trainer is a learner's)."""

    cfg: TrainConfig
    """the trainer's settings (the learner reads its own section, e.g. `cfg.ppo`)"""
    model: HierarchicalPolicy
    """q, the prior and the normaliser frozen; `model.pi` is the learner's to train"""
    envs: VectorEnv
    """the training envs, `LearnerEntry.num_envs` of them"""
    device: torch.device
    K: int
    """number of codes"""
    eye: torch.Tensor
    """(K, K) identity on the device: code -> one-hot"""
    discrete: bool
    """whether actions are discrete"""
    gen: torch.Generator
    """the trainer's torch generator (minibatches, replay samples, noise): saved in checkpoints"""
    np_rng: np.random.Generator
    """the trainer's NumPy generator (rollout noise, codes): saved in checkpoints"""
    expert: ExpertData
    """the demonstrations as tensors (for a BC term)"""
    iteration: int
    """completed training iterations (the trainer counts them)"""
    global_step: int
    """env steps so far; the learner adds the steps it takes"""
    rollout_state: RolloutState | None
    """where the envs stand (None: fresh episodes are due, `reset_envs`)"""
    reward: Reward
    """the imitation reward (`digail.algos.rewards`): the learner hands it the agent's steps (`Reward.update`), asks
    what they earn (`Reward.rewards`) and logs its scalars"""

    def reset_envs(self) -> RolloutState: ...
    def env_actions(self, acts: np.ndarray) -> np.ndarray: ...
    def to_env_actions(self, acts: Any) -> Any: ...
    def act_input(self, acts: torch.Tensor) -> torch.Tensor: ...
    def choose_codes(self, obs_n: np.ndarray, prev: np.ndarray, t_ep: np.ndarray,
                     env_idx: np.ndarray) -> tuple[np.ndarray, np.ndarray]: ...
    def start_episodes(self, idx: np.ndarray) -> None: ...
    def episode_done(self, i: int) -> None: ...
    def frozen_codes(self) -> AbstractContextManager[None]: ...
    def episode_scalars(self) -> dict[str, float]: ...
    def update_macro_policy(self, batch: dict[str, torch.Tensor]) -> dict[str, float]: ...
    def with_bonus(self, imitation: torch.Tensor, batch: dict[str, torch.Tensor]
                   ) -> tuple[torch.Tensor, torch.Tensor]: ...


class Learner(Protocol):
    """A policy learner: one training iteration at a time, and its state for checkpoints."""

    total_iterations: int
    """the run's length in iterations, for schedules over it (`GAIL.train` sets it)"""

    def iterate(self) -> dict[str, float]:
        """Collect (or receive) transitions, update pi (and the learner's own nets), and return the iteration's
        scalars; the trainer counts the iteration once this returns."""
        ...

    def state_dict(self) -> dict[str, Any]:
        """The learner's own state, stored at the top level of the training checkpoint beside the trainer's keys."""
        ...

    def load_state_dict(self, state: dict[str, Any]) -> None:
        """Restore from a whole training checkpoint (the learner picks its own keys)."""
        ...


@dataclass(frozen=True)
class LearnerEntry:
    """One row of the learner registry."""

    build: Callable[[Host], Learner]
    """the learner of a trainer (raises `UserError` for settings it cannot run)"""
    num_envs: Callable[[TrainConfig], int]
    """how many envs the trainer makes for it"""
    absorbing: Callable[[TrainConfig], bool] = lambda cfg: False
    """whether it uses absorbing states (DAC): a reward then also pays the absorbing state (D's rows carry a flag)"""
