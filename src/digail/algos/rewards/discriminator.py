"""The discriminator D(s, a) (`logits_expert_is_high`), the policy's reward from its logits, and its updates: binary
cross-entropy with the expert labelled 1.

`discriminator_update` runs passes of minibatches over an on-policy rollout (PPO's iteration); `PenaltyStep` is one
step on replayed pairs with DAC's gradient penalty (SAC's, interleaved with the env steps).
"""

from __future__ import annotations

from collections.abc import Sequence

import torch
from torch import nn

from digail.algos import fast
from digail.algos.fast.mlp import plain_layers
from digail.algos.fast.step import FusedAdamState
from digail.algos.ppo import maybe_compiled
from digail.nets.mlp import mlp


class Discriminator(nn.Module):
    """D_omega(s, a) returning `logits_expert_is_high`: sigmoid(logit) = D = P(expert | s, a).

    Trained with binary cross-entropy, expert pairs labelled 1 and agent pairs 0. Actions enter as one-hots for
    discrete spaces and as the executed (clipped / canonical) action for continuous ones.
    """

    def __init__(self, obs_dim: int, act_dim: int, hidden: Sequence[int] = (64, 64)) -> None:
        super().__init__()
        self.net = mlp(obs_dim + act_dim, 1, hidden)

    def forward(self, obs_n: torch.Tensor, act_in: torch.Tensor) -> torch.Tensor:
        return self.net(torch.cat([obs_n, act_in], -1)).squeeze(-1)


def generator_reward(logits_expert_is_high: torch.Tensor, kind: str = "positive") -> torch.Tensor:
    """Reward for the policy from D's logits l, with D = sigmoid(l) the probability of 'expert'.

    - positive: -log(1 - D) = softplus(l) >= 0. A survival bonus: right for envs that terminate on failure
      (Hopper, Walker), since each step alive earns reward.
    - negative: log D = -softplus(-l) <= 0. A step cost: pushes towards ending episodes early.
    - logit: log D - log(1 - D) = l, the AIRL-style reward, unbiased about episode length.
    The paper writes the GAN objective with the policy minimising E[log D(s, a)] where D scores the *agent*;
    with our expert-is-high D the policy maximises any of the above.
    """
    if kind == "positive":
        return nn.functional.softplus(logits_expert_is_high)
    if kind == "negative":
        return -nn.functional.softplus(-logits_expert_is_high)
    if kind == "logit":
        return logits_expert_is_high
    raise ValueError(f"unknown reward kind {kind!r}")


def disc_loss(disc: Discriminator, x_agent: torch.Tensor, x_expert: torch.Tensor
              ) -> tuple[torch.Tensor, torch.Tensor]:
    """D's binary cross-entropy on ready [obs, action] inputs, agent labelled 0 and expert 1; also the detached
    (loss, agent accuracy, expert accuracy)."""
    logits_agent, logits_expert = disc.net(x_agent).squeeze(-1), disc.net(x_expert).squeeze(-1)
    bce = nn.functional.binary_cross_entropy_with_logits
    loss = bce(logits_agent, torch.zeros_like(logits_agent)) + bce(logits_expert, torch.ones_like(logits_expert))
    parts = torch.stack([loss, (logits_agent < 0).float().mean(), (logits_expert > 0).float().mean()])
    return loss, parts.detach()


def gradient_penalty(disc: Discriminator, x_agent: torch.Tensor, x_expert: torch.Tensor,
                     gen: torch.Generator) -> torch.Tensor:
    """DAC's penalty (|grad_x D(x)| - 1)^2, averaged over points drawn uniformly on the segments between paired
    agent and expert rows: it keeps D's logits from turning into a step between the two sets, which a handful of
    demonstrations otherwise lets D learn by heart (every agent step then earns the same near-zero reward)."""
    alpha = torch.rand(len(x_agent), 1, generator=gen).to(x_agent)
    mix = (alpha * x_agent + (1 - alpha) * x_expert).requires_grad_(True)
    (grad,) = torch.autograd.grad(disc.net(mix).sum(), mix, create_graph=True)
    return (grad.norm(dim=-1) - 1).pow(2).mean()


def discriminator_update(disc: Discriminator, optimizer: torch.optim.Optimizer, x_agent: torch.Tensor,
                         x_expert: torch.Tensor, *, updates: int, minibatch_size: int, gen: torch.Generator,
                         compile: bool = False, grad_penalty: float = 0.0) -> dict[str, float]:
    """`updates` passes of Adam steps on D: each minibatch is half a shuffled slice of the agent's [obs, action]
    rows `x_agent` (label 0), half rows drawn at random from the expert's `x_expert` (label 1); with
    `grad_penalty` > 0 the loss gains that weight times `gradient_penalty` on the minibatch.

    Returns the mean loss and accuracies as `disc/*` scalars.
    """
    n = len(x_agent)
    # a rollout smaller than half a minibatch is one minibatch (else the loop below would never step D)
    half = max(1, min(minibatch_size // 2, n))
    loss_fn = maybe_compiled(disc_loss, compile)
    stats = []
    for _ in range(updates):
        perm = torch.randperm(n, generator=gen)
        for start in range(0, n - half + 1, half):
            e_idx = torch.randint(len(x_expert), (half,), generator=gen)
            x_a, x_e = x_agent[perm[start:start + half]], x_expert[e_idx]
            loss, parts = loss_fn(disc, x_a, x_e)
            if grad_penalty > 0:
                loss = loss + grad_penalty * gradient_penalty(disc, x_a, x_e, gen)
            optimizer.zero_grad(set_to_none=True)
            loss.backward()
            optimizer.step()
            stats.append(parts)
    loss_mean, acc_agent, acc_expert = torch.stack(stats).mean(0).tolist() if stats else [0.0] * 3
    return {"disc/loss": loss_mean, "disc/acc_agent": acc_agent, "disc/acc_expert": acc_expert,
            "disc/accuracy": 0.5 * (acc_agent + acc_expert)}


class PenaltyStep:
    """One Adam step of D on ready inputs with the gradient penalty (|grad D| - 1)^2 on mixed points (DAC), and D's
    logits; on the fast path both run the hand-written gradients of `digail.algos.fast.sac_grad`.

    Args:
        disc: D, updated in place.
        optimizer: D's Adam.
    """

    def __init__(self, disc: Discriminator, optimizer: torch.optim.Optimizer) -> None:
        self.disc, self.optimizer = disc, optimizer
        d_lin = plain_layers(disc.net)
        self.hand = fast.enabled() and d_lin is not None
        """whether D's step runs the hand-written gradient of `digail.algos.fast.sac_grad.disc_grads`"""
        self._d_w = [m.weight for m in d_lin or []]
        self._d_b = [m.bias for m in d_lin or []]
        self._d_params = [*self._d_w, *self._d_b]
        self._d_adam = FusedAdamState(optimizer, self._d_params)

    def logits(self, x: torch.Tensor) -> torch.Tensor:
        """D's logits (n,) for its inputs x (n, .)."""
        if self.hand:
            from digail.algos.fast.mlp import output
            from digail.algos.fast.scripting import scripted

            return scripted(output)(x, self._d_w, self._d_b).squeeze(-1)
        return self.disc.net(x).squeeze(-1)

    def __call__(self, x_agent: torch.Tensor, x_expert: torch.Tensor, mix: torch.Tensor,
                 grad_penalty: float) -> torch.Tensor:
        """The step on agent rows `x_agent` (label 0), expert rows `x_expert` (label 1) and the penalty's points
        `mix` (empty without a penalty); returns the detached [loss, agent accuracy, expert accuracy, penalty]."""
        adam = self._d_adam.lists() if self.hand else None
        if adam is not None:
            from digail.algos.fast.sac_grad import disc_update
            from digail.algos.fast.scripting import scripted

            with torch.no_grad():
                return scripted(disc_update)(x_agent, x_expert, mix, self._d_params, grad_penalty, *adam)
        if self.hand:  # until D's optimiser holds its state (its own first step creates it)
            from digail.algos.fast.sac_grad import disc_grads
            from digail.algos.fast.scripting import scripted

            with torch.no_grad():
                grads, parts = scripted(disc_grads)(x_agent, x_expert, mix, self._d_w, self._d_b, grad_penalty)
            for p, g in zip(self._d_params, grads, strict=True):
                p.grad = g
            self.optimizer.step()
            return parts
        loss, parts = disc_loss(self.disc, x_agent, x_expert)
        penalty = loss.new_zeros(())
        if grad_penalty > 0:
            mix = mix.requires_grad_(True)
            (g,) = torch.autograd.grad(self.disc.net(mix).sum(), mix, create_graph=True)
            penalty = (g.norm(dim=1) - 1.0).pow(2).mean()
            loss = loss + grad_penalty * penalty
        self.optimizer.zero_grad(set_to_none=True)
        loss.backward()
        self.optimizer.step()
        return torch.cat([parts, penalty.detach()[None]])
