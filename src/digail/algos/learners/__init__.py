"""The policy learners of the adversarial trainer, by `TrainConfig.learner` name (the interface: `base`)."""

from __future__ import annotations

from digail.algos.learners.base import Host, Learner, LearnerEntry
from digail.algos.learners.ppo import PPOLearner
from digail.algos.learners.sac import SACLearner

__all__ = ["LEARNERS", "Host", "Learner", "LearnerEntry", "PPOLearner", "SACLearner"]

LEARNERS: dict[str, LearnerEntry] = {
    "ppo": LearnerEntry(build=PPOLearner, num_envs=lambda cfg: cfg.ppo.num_envs),
    "sac": LearnerEntry(build=SACLearner, num_envs=lambda cfg: cfg.sac.num_envs,
                        absorbing=lambda cfg: cfg.sac.absorbing),
}
"""name -> how to build the learner and what it needs of the trainer (its env count, absorbing states)"""
