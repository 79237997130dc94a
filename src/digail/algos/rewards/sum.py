"""Rewards that add up: a weighted sum of terms, and the env's own reward as a term.

`--train.imitation.terms env:0.1` pays the imitation reward plus a tenth of the env's reward: a goal or success term
is one class here (or in a module of its own) and one row of `digail.algos.rewards.REWARDS`.
"""

from __future__ import annotations

from typing import Any

import torch

from digail.algos.rewards.base import EnvStep, Reward, RewardHost, Rollout, Steps
from digail.algos.rewards.views import RewardInputs
from digail.errors import UserError


class EnvReward:
    """The env's own reward for each step (`rews` of the rollout or the replayed transitions; 0 in the absorbing
    state): nothing to learn.

    Args:
        host: the trainer (unused: the reward is in the steps).
        inputs: unused.
        kind: `env`.
    """

    def __init__(self, host: RewardHost, inputs: RewardInputs, kind: str = "env") -> None:
        del host, inputs, kind

    def update(self, agent: Rollout | EnvStep) -> None:
        pass

    def rewards(self, steps: Steps) -> torch.Tensor:
        return steps.batch["rews"].float()

    def scalars(self) -> dict[str, float]:
        return {}

    def state_dict(self) -> dict[str, Any]:
        return {}

    def load_state_dict(self, state: dict[str, Any]) -> None:
        pass


class WeightedSum:
    """The sum of reward terms, each times its weight: r = sum_i w_i r_i.

    Each term learns from every update in the order given and keeps its own checkpoint keys and scalars, so two
    terms whose keys would collide (two D-based ones, two optimal-transport ones) are refused.

    Args:
        terms: (weight, reward) pairs.
    """

    def __init__(self, terms: list[tuple[float, Reward]]) -> None:
        if not terms:
            raise ValueError("a weighted sum needs at least one term")
        self.terms = terms
        seen: set[str] = set()
        for _, term in terms:
            keys = set(term.state_dict())
            if keys & seen:
                raise UserError(f"two reward terms keep their state under the same keys "
                                f"({', '.join(sorted(keys & seen))}); add at most one D-based and one "
                                "optimal-transport term.")
            seen |= keys

    def update(self, agent: Rollout | EnvStep) -> None:
        for _, term in self.terms:
            term.update(agent)

    def rewards(self, steps: Steps) -> torch.Tensor:
        total: torch.Tensor | None = None
        for weight, term in self.terms:
            r = weight * term.rewards(steps)
            total = r if total is None else total + r
        assert total is not None
        return total

    def scalars(self) -> dict[str, float]:
        return {k: v for _, term in self.terms for k, v in term.scalars().items()}

    def state_dict(self) -> dict[str, Any]:
        return {k: v for _, term in self.terms for k, v in term.state_dict().items()}

    def load_state_dict(self, state: dict[str, Any]) -> None:
        for _, term in self.terms:
            term.load_state_dict(state)
