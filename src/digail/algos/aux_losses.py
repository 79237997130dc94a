"""The policy's optional extra terms beside PPO's loss (`ppo_update(aux_losses=...)`): BC / L2 on the expert's
pairs (the paper's Fetch experiment) and the anchor to the initial policy."""

from __future__ import annotations

from collections.abc import Callable

import torch

from digail.algos.expert_data import ExpertData
from digail.algos.ppo import PPOBatch
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


def anchor_loss(pi: SubtaskPolicy, anchor: SubtaskPolicy, batch: PPOBatch, batch_size: int, gen: torch.Generator
                ) -> Callable[[], torch.Tensor]:
    """The anchor term on `batch`'s own states: squared distance between pi's mean action (or logits) and the
    frozen initial policy `anchor`'s, on a fresh random subset of `batch_size` states per call."""

    def loss() -> torch.Tensor:
        idx = torch.randint(len(batch), (batch_size,), generator=gen)
        obs, codes = batch.obs[idx], batch.codes[idx]
        with torch.no_grad():
            target = anchor.net(anchor.inputs(obs, codes))
        return (pi.net(pi.inputs(obs, codes)) - target).pow(2).sum(-1).mean()

    return loss
