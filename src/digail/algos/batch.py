"""The flattened rollout one PPO update and the policy's extra terms read (its own module: both `ppo` and
`aux_losses` use it, and `ppo` uses `aux_losses`)."""

from __future__ import annotations

from dataclasses import dataclass

import torch


@dataclass(frozen=True)
class PPOBatch:
    """Flattened rollout: `b_` tensors of length B (obs already normalised, codes one-hot)."""

    obs: torch.Tensor
    codes: torch.Tensor
    acts: torch.Tensor
    logp: torch.Tensor
    adv: torch.Tensor
    returns: torch.Tensor

    def __len__(self) -> int:
        return len(self.obs)
