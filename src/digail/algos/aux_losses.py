"""The policy's optional extra terms beside PPO's loss (`ppo_update(aux_losses=...)`): BC / L2 on the expert's
pairs (the paper's Fetch experiment) and the anchor to the initial policy."""

from __future__ import annotations

from dataclasses import dataclass

import torch

from digail.algos.batch import PPOBatch
from digail.algos.expert_data import ExpertData
from digail.nets.policy import SubtaskPolicy


def bc_loss(pi: SubtaskPolicy, expert: ExpertData, eye: torch.Tensor, batch_size: int, gen: torch.Generator, *,
            discrete: bool) -> torch.Tensor:
    """BC / L2 term on `batch_size` random expert (s, c_E) -> a_E: squared error of pi's mean (continuous) or
    its NLL (discrete); `eye` turns codes into one-hots."""
    idx = torch.randint(len(expert.obs_n), (batch_size,), generator=gen)
    code_1h = eye[expert.codes[idx]]
    if discrete:
        return -pi.dist(expert.obs_n[idx], code_1h).log_prob(expert.acts[idx]).mean()
    mean = pi.mode(expert.obs_n[idx], code_1h)
    return (mean - expert.acts[idx]).pow(2).sum(-1).mean()


@dataclass(frozen=True, eq=False)
class AnchorLoss:
    """The anchor term on `batch`'s own states: squared distance between pi's mean action (or logits) and the
    frozen initial policy `anchor`'s, on a fresh random subset of `batch_size` states per call.

    A callable object rather than a closure so that `ppo_update` can recognise it and compute it inside its
    hand-written gradient (`ppo_grad`), drawing the same random rows.
    """

    pi: SubtaskPolicy
    anchor: SubtaskPolicy
    batch: PPOBatch
    batch_size: int
    gen: torch.Generator

    def rows(self) -> torch.Tensor:
        """The next call's random rows of `batch` (each call draws these, then evaluates on them)."""
        return torch.randint(len(self.batch), (self.batch_size,), generator=self.gen)

    def __call__(self) -> torch.Tensor:
        idx = self.rows()
        obs, codes = self.batch.obs[idx], self.batch.codes[idx]
        with torch.no_grad():
            target = self.anchor.net(self.anchor.inputs(obs, codes))
        return (self.pi.net(self.pi.inputs(obs, codes)) - target).pow(2).sum(-1).mean()


def anchor_loss(pi: SubtaskPolicy, anchor: SubtaskPolicy, batch: PPOBatch, batch_size: int, gen: torch.Generator
                ) -> AnchorLoss:
    """The anchor term (`AnchorLoss`) as an aux loss for `ppo_update`."""
    return AnchorLoss(pi, anchor, batch, batch_size, gen)
