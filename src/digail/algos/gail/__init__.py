"""The adversarial trainer: GAIL on pi(a | s, c), driving one learner and one reward.

`GAIL` (`trainer`) owns the demonstrations, the codes and the bonus, and drives one learner
(`digail.algos.learners`) and one imitation reward (`digail.algos.rewards`); `DirectedInfoGAIL`
(`digail.algos.directed_info_gail`) extends it with the macro-policy's codes and the directed-info bonus.
"""

from __future__ import annotations

from digail.algos.gail.trainer import CHECKPOINT_VERSION, GAIL

__all__ = ["CHECKPOINT_VERSION", "GAIL"]
