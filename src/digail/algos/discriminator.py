"""The discriminator's update: binary cross-entropy of D(s, a) with the expert labelled 1 (`logits_expert_is_high`)."""

from __future__ import annotations

import torch
from torch import nn

from digail.algos.fast.step import LeanStep
from digail.algos.ppo import maybe_compiled
from digail.nets.critic import Discriminator


def disc_loss(disc: Discriminator, x_agent: torch.Tensor, x_expert: torch.Tensor
              ) -> tuple[torch.Tensor, torch.Tensor]:
    """D's binary cross-entropy on ready [obs, action] inputs, agent labelled 0 and expert 1; also the detached
    (loss, agent accuracy, expert accuracy)."""
    logits_agent, logits_expert = disc.net(x_agent).squeeze(-1), disc.net(x_expert).squeeze(-1)
    bce = nn.functional.binary_cross_entropy_with_logits
    loss = bce(logits_agent, torch.zeros_like(logits_agent)) + bce(logits_expert, torch.ones_like(logits_expert))
    parts = torch.stack([loss, (logits_agent < 0).float().mean(), (logits_expert > 0).float().mean()])
    return loss, parts.detach()


def discriminator_update(disc: Discriminator, optimizer: torch.optim.Optimizer, x_agent: torch.Tensor,
                         x_expert: torch.Tensor, *, updates: int, minibatch_size: int, gen: torch.Generator,
                         compile: bool = False) -> dict[str, float]:
    """`updates` passes of Adam steps on D: each minibatch is half a shuffled slice of the agent's [obs, action]
    rows `x_agent` (label 0), half rows drawn at random from the expert's `x_expert` (label 1).

    Returns the mean loss and accuracies as `disc/*` scalars.
    """
    n = len(x_agent)
    half = max(1, minibatch_size // 2)
    loss_fn = maybe_compiled(disc_loss, compile)
    step = LeanStep(optimizer, None)
    stats = []
    for _ in range(updates):
        perm = torch.randperm(n, generator=gen)
        for start in range(0, n - half + 1, half):
            e_idx = torch.randint(len(x_expert), (half,), generator=gen)
            loss, parts = loss_fn(disc, x_agent[perm[start:start + half]], x_expert[e_idx])
            optimizer.zero_grad(set_to_none=True)
            loss.backward()
            step()
            stats.append(parts)
    loss_mean, acc_agent, acc_expert = torch.stack(stats).mean(0).tolist() if stats else [0.0] * 3
    return {"disc/loss": loss_mean, "disc/acc_agent": acc_agent, "disc/acc_expert": acc_expert,
            "disc/accuracy": 0.5 * (acc_agent + acc_expert)}
