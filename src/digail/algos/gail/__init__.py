"""The adversarial trainer: GAIL on pi(a | s, c), with the discriminator's updates beside it.

`GAIL` (`trainer`) owns the demonstrations, D, the codes and the reward, and drives one learner
(`digail.algos.learners`); `DirectedInfoGAIL` (`digail.algos.directed_info_gail`) extends it with the macro-policy's
codes and the directed-info bonus.
"""

from __future__ import annotations

from digail.algos.gail.trainer import CHECKPOINT_VERSION, GAIL, RewardFn

__all__ = ["CHECKPOINT_VERSION", "GAIL", "RewardFn"]
