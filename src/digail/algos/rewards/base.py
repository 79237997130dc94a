"""The interface between the adversarial trainer and an imitation reward.

A reward says how much each agent step looks like the demonstrations. A D-based reward (`disc`: GAIL's binary
cross-entropy, the positive-unlabeled objective, D's regularisers) owns the discriminator D and its updates; an
optimal-transport reward (`ot`) owns the demonstrations' view and matches whole episodes against them, with no D
to train. The trainer adds the directed-info bonus to whatever the reward gives, and its learners (PPO, SAC) reach
the reward only through the trainer (`digail.algos.learners.base.Host`).

Adding a reward is one module in `digail.algos.rewards` with a class that satisfies `Reward` (constructed from a
`RewardHost`) and one `RewardEntry` in `digail.algos.rewards.REWARDS`, under the name `--train.imitation.kind`
takes (`digail.imitation_config.REWARD_KINDS`).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import Any, Protocol

import torch

from digail.algos.expert_data import ExpertData
from digail.config import TrainConfig
from digail.nets.critic import Discriminator

LogitsReward = Callable[[torch.Tensor, dict[str, torch.Tensor]], torch.Tensor]
"""(D's logits_expert_is_high, the batch) -> the reward of those steps (the trainer's `reward_fn`)"""


class RewardHost(Protocol):
    """What a reward may use of its trainer."""

    cfg: TrainConfig
    device: torch.device
    K: int
    gen: torch.Generator
    """the trainer's torch generator (D's minibatches and noise): saved in checkpoints"""
    reward_fn: LogitsReward
    """D's logits -> the policy's reward (`--train.reward`); D-based rewards score with it"""

    @property
    def expert(self) -> ExpertData: ...
    @property
    def expert_disc_in(self) -> torch.Tensor: ...
    @property
    def absorbing(self) -> bool: ...
    @property
    def disc_in_dims(self) -> tuple[int, int]:
        """(D's observation part, including the absorbing flag; D's action part)"""
        ...

    def disc_input(self, obs_n: torch.Tensor, act_in: torch.Tensor) -> torch.Tensor: ...
    def disc_features(self, obs_n: torch.Tensor) -> torch.Tensor:
        """D's view of normalised observations (`--train.disc-obs`): what an optimal-transport reward compares"""
        ...


class Reward(Protocol):
    """An imitation reward: how it learns (if it does) and what it pays each agent step, on-policy and off."""

    @property
    def disc(self) -> Discriminator | None:
        """D, for a reward that learns one; None for one that does not (optimal transport)"""
        ...

    def update(self, obs_n: torch.Tensor, act_in: torch.Tensor, *, compile: bool = False) -> dict[str, float]:
        """On-policy: learn from a rollout's (normalised obs, D-action) pairs; returns `disc/*` scalars."""
        ...

    def step(self, x_agent: torch.Tensor, x_expert: torch.Tensor, mix: torch.Tensor,
             grad_penalty: float) -> torch.Tensor:
        """Off-policy: one step of D on ready agent and expert rows (penalty points `mix`); returns the detached
        [loss, agent accuracy, expert accuracy, penalty]."""
        ...

    def logits(self, x: torch.Tensor) -> torch.Tensor:
        """D's logits (n,) for ready input rows (a reward without D raises)."""
        ...

    def rollout_rewards(self, batch: dict[str, torch.Tensor], obs_n: torch.Tensor,
                        act_in: torch.Tensor) -> torch.Tensor:
        """On-policy: the reward (T, N) of a rollout's steps; `obs_n`, `act_in` are its (T * N) flat pairs."""
        ...

    def replay_rewards(self, b: dict[str, torch.Tensor], idx: torch.Tensor) -> torch.Tensor:
        """Off-policy: the reward (B,) of replayed transitions `b` at buffer positions `idx`."""
        ...

    def observe(self, idx: Any, obs_n: torch.Tensor, codes: torch.Tensor, done: Any) -> None:
        """Off-policy: the steps just stored at buffer positions `idx` (one per env: normalised s_t, c_t, and
        whether the env's episode ended with it)."""
        ...

    def flush(self) -> None:
        """Off-policy: the episodes under way end here (the envs restart); score what they hold."""
        ...

    def scalars(self) -> dict[str, float]:
        """The reward's own scalars of the last iteration (`reward/*`)."""
        ...

    def state_dict(self) -> dict[str, Any]:
        """The reward's state, stored at the top level of the training checkpoint beside the trainer's keys."""
        ...

    def load_state_dict(self, state: dict[str, Any]) -> None:
        """Restore from a whole training checkpoint (the reward picks its own keys)."""
        ...


@dataclass(frozen=True)
class RewardEntry:
    """One row of the reward registry."""

    build: Callable[[RewardHost], Reward]
    """the reward of a trainer (raises `UserError` for settings it cannot run)"""
