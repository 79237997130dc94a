"""The imitation rewards of the adversarial trainer, by `--train.imitation.kind` name (the interface: `base`)."""

from __future__ import annotations

from digail.algos.rewards.base import Reward, RewardEntry, RewardHost
from digail.algos.rewards.disc import DiscReward, pu_loss
from digail.algos.rewards.ot import OTReward, sinkhorn_plan

__all__ = ["REWARDS", "DiscReward", "OTReward", "Reward", "RewardEntry", "RewardHost", "pu_loss", "sinkhorn_plan"]

REWARDS: dict[str, RewardEntry] = {
    "bce": RewardEntry(build=DiscReward),
    "pu": RewardEntry(build=DiscReward),
    "ot": RewardEntry(build=OTReward),
    "ot-subtask": RewardEntry(build=OTReward),
}
"""name -> how to build the reward (`digail.imitation_config.REWARD_KINDS` lists the same names)"""
