"""The policy's optional extra terms beside PPO's loss (`ppo_update(aux_losses=...)`): BC / L2 on the expert's
pairs (the paper's Fetch experiment) and the anchor to the initial policy.

An aux term is any callable returning a scalar loss with its graph (`AuxLoss`). A term the hand-written PPO
gradient (`digail.algos.fast.ppo_grad`) can compute itself also offers `hand_grad_terms` (`HandGradTerm`)."""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import Protocol

import torch

from digail.algos.batch import PPOBatch
from digail.algos.expert_data import ExpertData
from digail.nets.policy import SubtaskPolicy


class AuxLoss(Protocol):
    """An extra term of the policy's loss, evaluated once per minibatch."""

    def __call__(self) -> torch.Tensor: ...


class HandGradTerm(AuxLoss, Protocol):
    """An aux term that the hand-written PPO gradient can compute itself: the squared distance between pi's
    outputs and fixed targets on rows of the update's batch."""

    def hand_grad_terms(self, policy: SubtaskPolicy, batch: PPOBatch
                        ) -> tuple[Callable[[], torch.Tensor], torch.Tensor] | None:
        """(a function drawing the next minibatch's rows, the targets on every row of `batch`), or None where the
        term does not take that form for this policy and batch."""
        ...


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

    A `HandGradTerm`: `ppo_update`'s hand-written gradient can compute it itself, drawing the same random rows.
    """

    pi: SubtaskPolicy
    anchor: SubtaskPolicy
    batch: PPOBatch
    batch_size: int
    gen: torch.Generator

    def rows(self) -> torch.Tensor:
        """The next call's random rows of `batch` (each call draws these, then evaluates on them)."""
        return torch.randint(len(self.batch), (self.batch_size,), generator=self.gen)

    def hand_grad_terms(self, policy: SubtaskPolicy, batch: PPOBatch
                        ) -> tuple[Callable[[], torch.Tensor], torch.Tensor] | None:
        """`rows` and the anchor's outputs on all of `batch`, where this term is on `policy` and `batch` and its
        anchor cannot move during the update (no parameter of it trains)."""
        if self.pi is not policy or self.batch is not batch or any(p.requires_grad for p in self.anchor.parameters()):
            return None
        with torch.no_grad():
            targets = self.anchor.net(self.anchor.inputs(batch.obs, batch.codes))
        return self.rows, targets

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


def qfiltered_bc_loss(pi: SubtaskPolicy, expert: ExpertData, eye: torch.Tensor, batch_size: int,
                      gen: torch.Generator, critic: Callable[[torch.Tensor], torch.Tensor],
                      to_env: Callable[[torch.Tensor], torch.Tensor]) -> tuple[torch.Tensor, torch.Tensor]:
    """The BC / L2 term kept only where it still teaches (ROT's Q-filter, after Nair et al. 2018): on
    `batch_size` random expert steps (s, c_E, a_E), the squared error of pi's mean counts where the critics value
    the expert's action above the policy's, min_i Q_i(s, c_E, a_E) > min_i Q_i(s, c_E, pi(s, c_E)); elsewhere the
    policy already does better by the critics' account and the term steps aside.

    `critic` maps [s, one-hot c, executed a] rows to the twin critics' values (2, n); `to_env` maps sampled
    actions to executed ones. Returns the loss (mean over all drawn steps, so its scale falls as the filter
    closes) and the detached share of steps kept."""
    idx = torch.randint(len(expert.obs_n), (batch_size,), generator=gen)
    obs, code_1h, acts = expert.obs_n[idx], eye[expert.codes[idx]], expert.acts[idx]
    mean = pi.mode(obs, code_1h)
    with torch.no_grad():
        obs_code = torch.cat([obs, code_1h], -1)
        q_expert = critic(torch.cat([obs_code, to_env(acts)], -1)).min(0).values
        q_policy = critic(torch.cat([obs_code, to_env(mean.detach())], -1)).min(0).values
        keep = (q_expert > q_policy).to(mean.dtype)
    return ((mean - acts).pow(2).sum(-1) * keep).mean(), keep.mean()
