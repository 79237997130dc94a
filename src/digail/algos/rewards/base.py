"""The interface between the adversarial trainer's learners and an imitation reward.

A reward says how much each agent step looks like the demonstrations. A D-based reward (`disc`: GAIL's binary
cross-entropy, the positive-unlabeled objective, D's regularisers) owns the discriminator D, its inputs and its
updates; an optimal-transport reward (`ot`) matches whole episodes against the demonstrations, with no D to train;
`WeightedSum` (`sum`) adds terms up. The trainer adds the directed-info bonus to whatever the reward gives; its
learners (PPO, SAC) hand the reward the agent's steps (`update`) and ask what those steps earn (`rewards`), and know
nothing else of it.

Adding a reward is one module in `digail.algos.rewards` with a class that satisfies `Reward` (constructed from a
`RewardHost` and the shared `digail.algos.rewards.views.RewardInputs`) and one row in
`digail.algos.rewards.REWARDS`, under a name of `digail.imitation_config.RewardKind`.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import Any, Protocol

import numpy as np
import torch

from digail.algos.expert_data import ExpertData
from digail.config import TrainConfig
from digail.data.trajectory import Trajectory
from digail.nets.vae import HierarchicalPolicy

LogitsReward = Callable[[torch.Tensor, dict[str, torch.Tensor]], torch.Tensor]
"""(D's logits_expert_is_high, the steps' batch) -> the reward of those steps, for a D-based reward (e.g.
`lambda logits, batch: batch["rews"]` pays the env's own reward)"""


@dataclass(frozen=True)
class Steps:
    """Agent steps as a reward reads them: what it learns from (`Reward.update`) and what it pays (`Reward.rewards`)."""

    obs: torch.Tensor
    """(n, obs_dim) normalised observations s_t, flat"""
    acts: torch.Tensor
    """(n, A) the actions as rewards see them: one-hot (discrete) or as the env executes them (continuous)"""
    batch: dict[str, torch.Tensor]
    """the columns the steps come from: a rollout's (T, N) with T * N = n (`codes`, `terminated`, `truncated`,
    `ep_offset`, `rews`, ...) or replayed transitions' (n,) (`terminated`, `rews`, ...)"""
    idx: torch.Tensor | None = None
    """replayed transitions: their replay buffer positions; None for a rollout's steps"""
    absorbing: bool = False
    """the steps are DAC's absorbing state (their `obs` and `acts` are not read)"""


@dataclass(frozen=True)
class Rollout:
    """On-policy: a whole rollout to learn from."""

    steps: Steps
    compile: bool = False
    """run a D's loss through `torch.compile` (the PPO learner's `--train.ppo.compile`)"""


@dataclass(frozen=True)
class EnvStep:
    """Off-policy: the transitions one batched env step just stored in the replay buffer, one per env."""

    steps: Steps
    """their normalised observations s_t, actions and (in `batch`) `codes`; `idx` their buffer positions"""
    done: np.ndarray
    """(N,) bool: whether each env's episode ended with its step (terminated or truncated)"""
    first: np.ndarray
    """(N,) bool: whether each step began an episode (the envs restart at checkpoints: what was under way ends)"""
    sample: Callable[[int], Steps] | None
    """n stored transitions drawn with the trainer's generator; None until the learner updates (`learning_starts`)"""


class Reward(Protocol):
    """An imitation reward: how it learns from the agent's steps (if it does) and what it pays for them."""

    def update(self, agent: Rollout | EnvStep) -> None:
        """Learn from the agent's newest steps against the demonstrations: a whole rollout (on-policy), or the steps
        of one env step with the replay buffer behind them (off-policy)."""
        ...

    def rewards(self, steps: Steps) -> torch.Tensor:
        """The reward of `steps`: (T, N) for a rollout's, (n,) for replayed transitions or the absorbing state."""
        ...

    def scalars(self) -> dict[str, float]:
        """The reward's scalars since the last call (`disc/*`, `reward/*`); raises `TrainingError` where a loss of
        its own is not finite."""
        ...

    def state_dict(self) -> dict[str, Any]:
        """The reward's state, stored at the top level of the training checkpoint beside the trainer's keys."""
        ...

    def load_state_dict(self, state: dict[str, Any]) -> None:
        """Restore from a whole training checkpoint (the reward picks its own keys)."""
        ...


class RewardHost(Protocol):
    """What a reward may use of its trainer."""

    cfg: TrainConfig
    device: torch.device
    env_id: str
    seed: int
    K: int
    """number of codes"""
    gen: torch.Generator
    """the trainer's torch generator (D's minibatches and noise): saved in checkpoints"""
    iteration: int
    """completed training iterations (for messages)"""
    model: HierarchicalPolicy
    """its normaliser (fixed) maps the demonstrations' observations"""
    demos: list[Trajectory]
    expert: ExpertData
    """the demonstrations as tensors, and q's codes of them"""
    discrete: bool
    absorbing: bool
    """whether the learner uses absorbing states (DAC): D then judges the absorbing state too"""
    reward_fn: LogitsReward | None
    """D's logits -> the policy's reward (None: `--train.imitation.logits-to-reward`)"""

    def act_input(self, acts: torch.Tensor) -> torch.Tensor: ...

