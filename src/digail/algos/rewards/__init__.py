"""The imitation rewards of the adversarial trainer, by `--train.imitation.reward` name (the interface: `base`).

A reward is built from the trainer by `build_reward`: the named reward alone, or with `--train.imitation.terms` the
`WeightedSum` of it (weight 1) and the named terms.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from functools import partial

from digail.algos.rewards.base import EnvStep, LogitsReward, Reward, RewardHost, Rollout, Steps
from digail.algos.rewards.disc import DiscReward, pu_loss
from digail.algos.rewards.ot import OTReward, sinkhorn_plan
from digail.algos.rewards.sum import EnvReward, WeightedSum
from digail.algos.rewards.views import RewardInputs
from digail.imitation_config import REWARD_KINDS

__all__ = ["REWARDS", "DiscReward", "EnvReward", "EnvStep", "LogitsReward", "OTReward", "Reward", "RewardEntry",
           "RewardHost", "RewardInputs", "Rollout", "Steps", "WeightedSum", "build_reward", "pu_loss",
           "sinkhorn_plan"]


@dataclass(frozen=True)
class RewardEntry:
    """One row of the reward registry."""

    build: Callable[[RewardHost, RewardInputs], Reward]
    """the reward of a trainer, given the steps' views it shares with the other terms (raises `UserError` for
    settings it cannot run)"""


REWARDS: dict[str, RewardEntry] = {
    "bce": RewardEntry(build=partial(DiscReward, kind="bce")),
    "pu": RewardEntry(build=partial(DiscReward, kind="pu")),
    "ot": RewardEntry(build=partial(OTReward, kind="ot")),
    "ot-subtask": RewardEntry(build=partial(OTReward, kind="ot-subtask")),
    "env": RewardEntry(build=partial(EnvReward, kind="env")),
}
"""name -> how to build the reward, for every name of `digail.imitation_config.REWARD_KINDS` (which says what each
is, for the command line)"""

_missing = set(REWARD_KINDS) ^ set(REWARDS)
if _missing:
    raise ImportError(f"the reward names {sorted(_missing)} are in one of REWARD_KINDS and REWARDS only")


def build_reward(host: RewardHost) -> Reward:
    """The trainer's reward: `--train.imitation.reward`, plus each of `--train.imitation.terms` times its weight."""
    cfg = host.cfg.imitation
    inputs = RewardInputs(host)
    main = REWARDS[cfg.reward].build(host, inputs)
    if not cfg.terms:
        return main
    terms = [(weight, REWARDS[name].build(host, inputs)) for name, weight in cfg.term_weights]
    return WeightedSum([(1.0, main), *terms])
