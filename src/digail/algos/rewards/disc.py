"""D-based rewards: GAIL's discriminator trained by binary cross-entropy (`bce`) or as a positive-unlabeled
classifier (`pu`), optionally regularised (input noise, spectral normalisation, dropout, weight decay).

With a few demonstrations D separates them from the agent within a few iterations and its reward stops grading
what the agent does. The positive-unlabeled objective (Xu and Denil 2019) stops D from pushing every agent step
to "not expert": a share `pu_prior` of the agent's steps is taken as expert-like, and the non-negative risk
(Kiryo et al. 2017) keeps the agent's part of the loss from going below zero. The regularisers (goalGAIL's input
noise, Orsini et al.'s spectral normalisation, dropout and weight decay) keep D smooth between the two sets.
"""

from __future__ import annotations

import contextlib
from collections.abc import Iterator
from typing import Any

import torch
from torch import nn

from digail.algos.gail.discriminator import PenaltyStep, disc_loss, discriminator_update
from digail.algos.optim import adam
from digail.algos.rewards.base import RewardHost
from digail.errors import UserError
from digail.imitation_config import ImitationConfig
from digail.nets.critic import Discriminator


def pu_loss(logits_agent: torch.Tensor, logits_expert: torch.Tensor, prior: float) -> torch.Tensor:
    """The non-negative positive-unlabeled risk of D, expert steps positive and agent steps unlabeled:

        eta * E_E[-log D] + max(0, E_A[-log(1 - D)] - eta * E_E[-log(1 - D)])

    with eta = `prior`, the share of agent steps taken as expert-like. The second term is the risk of the
    negatives estimated from the unlabeled agent steps minus the expert-like share of them; clamped at 0, since a
    risk cannot be negative (where it would be, D is fitting the few expert steps by heart)."""
    softplus = nn.functional.softplus
    pos = softplus(-logits_expert).mean()  # -log D on expert steps
    neg_expert = softplus(logits_expert).mean()  # -log(1 - D) on expert steps
    neg_agent = softplus(logits_agent).mean()  # -log(1 - D) on agent steps
    return prior * pos + torch.clamp(neg_agent - prior * neg_expert, min=0.0)


class GenDropout(nn.Module):
    """Dropout whose masks come from the trainer's generator (saved in checkpoints), so that a resumed run drops the
    same units as the uninterrupted one; off in eval mode."""

    def __init__(self, p: float, gen: torch.Generator) -> None:
        super().__init__()
        self.p, self.gen = p, gen

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        if not self.training or self.p == 0:
            return x
        keep = torch.rand(x.shape, generator=self.gen).to(x) >= self.p
        return x * keep / (1.0 - self.p)


def regularised_net(in_dim: int, hidden: tuple[int, ...], cfg: ImitationConfig,
                    gen: torch.Generator) -> nn.Sequential:
    """D's MLP with the configured dropout after each hidden layer and spectral normalisation of every layer."""
    from digail.nets.mlp import mlp

    net = mlp(in_dim, 1, hidden)
    layers: list[nn.Module] = []
    for m in net:
        if isinstance(m, nn.Linear) and cfg.spectral_norm:
            m = nn.utils.parametrizations.spectral_norm(m)
        layers.append(m)
        if isinstance(m, nn.ReLU) and cfg.disc_dropout > 0:
            layers.append(GenDropout(cfg.disc_dropout, gen))
    return nn.Sequential(*layers)


class DiscReward:
    """The discriminator D(s, a) (`logits_expert_is_high`) and its updates; its reward is the trainer's
    `reward_fn` of D's logits (`--train.reward`: -log(1 - D) by default).

    With the plain settings (`bce`, no regulariser) its updates are GAIL's as they always were (the on-policy
    passes of `discriminator_update`, the off-policy `PenaltyStep`, on the fast path where it runs); otherwise
    they run on autograd with the configured loss and regularisers.

    Args:
        host: the trainer (D's input sizes, the demonstrations' rows, the generator, the reward of logits).
    """

    def __init__(self, host: RewardHost) -> None:
        self.host, self.cfg = host, host.cfg.imitation
        if self.cfg.kind == "pu" and host.absorbing:
            raise UserError("--train.imitation.kind pu does not score absorbing states; drop --train.sac.absorbing "
                            "or use --train.imitation.kind bce.")
        obs_dim, act_dim = host.disc_in_dims
        self.disc = Discriminator(obs_dim, act_dim, host.cfg.hidden).to(host.device)
        self.regularised = self.cfg.regularised
        """whether D's updates run the loss and regularisers on autograd instead of GAIL's plain steps"""
        if self.regularised:
            self.disc.net = regularised_net(obs_dim + act_dim, host.cfg.hidden, self.cfg, host.gen).to(host.device)
        self.optimizer = adam(list(self.disc.parameters()), lr=host.cfg.disc_lr)
        if self.cfg.disc_weight_decay > 0:
            for group in self.optimizer.param_groups:
                group["weight_decay"] = self.cfg.disc_weight_decay
        self.penalty_step = PenaltyStep(self.disc, self.optimizer)
        """D's plain off-policy step (and its logits), on the fast path where it runs"""
        self._stats: list[torch.Tensor] = []

    # ----------------------------------------------------------------------------------------------- scores
    @contextlib.contextmanager
    def _scoring(self) -> Iterator[None]:
        """D without dropout while it scores (its updates keep dropout on)."""
        if not self.regularised:
            yield
            return
        self.disc.eval()
        try:
            yield
        finally:
            self.disc.train()

    def logits(self, x: torch.Tensor) -> torch.Tensor:
        if not self.regularised:
            return self.penalty_step.logits(x)
        with self._scoring():
            return self.disc.net(x).squeeze(-1)

    def rollout_rewards(self, batch: dict[str, torch.Tensor], obs_n: torch.Tensor,
                        act_in: torch.Tensor) -> torch.Tensor:
        T, N = batch["logp"].shape
        with self._scoring():
            logits = self.disc.net(self.host.disc_input(obs_n, act_in)).reshape(T, N)
        return self.host.reward_fn(logits, batch)

    def replay_rewards(self, b: dict[str, torch.Tensor], idx: torch.Tensor) -> torch.Tensor:
        return self.host.reward_fn(self.logits(self.host.disc_input(b["obs"], b["acts"])), b)

    # ---------------------------------------------------------------------------------------------- updates
    def _loss(self, x_agent: torch.Tensor, x_expert: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """The configured loss on (noised) inputs, and the detached (loss, agent accuracy, expert accuracy)."""
        sigma = self.cfg.disc_noise
        if sigma > 0:
            x_agent = x_agent + sigma * torch.randn(x_agent.shape, generator=self.host.gen).to(x_agent)
            x_expert = x_expert + sigma * torch.randn(x_expert.shape, generator=self.host.gen).to(x_expert)
        if self.cfg.kind != "pu":
            return disc_loss(self.disc, x_agent, x_expert)
        logits_agent, logits_expert = self.disc.net(x_agent).squeeze(-1), self.disc.net(x_expert).squeeze(-1)
        loss = pu_loss(logits_agent, logits_expert, self.cfg.pu_prior)
        parts = torch.stack([loss, (logits_agent < 0).float().mean(), (logits_expert > 0).float().mean()])
        return loss, parts.detach()

    def _penalty(self, mix: torch.Tensor) -> torch.Tensor:
        mix = mix.requires_grad_(True)
        (g,) = torch.autograd.grad(self.disc.net(mix).sum(), mix, create_graph=True)
        return (g.norm(dim=1) - 1.0).pow(2).mean()

    def update(self, obs_n: torch.Tensor, act_in: torch.Tensor, *, compile: bool = False) -> dict[str, float]:
        h = self.host
        x_agent = h.disc_input(obs_n, act_in)
        if not self.regularised:
            return discriminator_update(self.disc, self.optimizer, x_agent, h.expert_disc_in,
                                        updates=h.cfg.disc_updates, minibatch_size=h.cfg.disc_minibatch_size,
                                        gen=h.gen, compile=compile, grad_penalty=h.cfg.disc_grad_penalty)
        # the same passes and minibatches as `discriminator_update`, with the configured loss
        x_expert_all, n = h.expert_disc_in, len(x_agent)
        half = max(1, min(h.cfg.disc_minibatch_size // 2, n))
        stats = []
        for _ in range(h.cfg.disc_updates):
            perm = torch.randperm(n, generator=h.gen)
            for start in range(0, n - half + 1, half):
                e_idx = torch.randint(len(x_expert_all), (half,), generator=h.gen)
                x_a, x_e = x_agent[perm[start:start + half]], x_expert_all[e_idx]
                loss, parts = self._loss(x_a, x_e)
                if h.cfg.disc_grad_penalty > 0:
                    alpha = torch.rand(len(x_a), 1, generator=h.gen).to(x_a)
                    loss = loss + h.cfg.disc_grad_penalty * self._penalty(alpha * x_a + (1 - alpha) * x_e)
                self.optimizer.zero_grad(set_to_none=True)
                loss.backward()
                self.optimizer.step()
                stats.append(parts)
        loss_mean, acc_agent, acc_expert = torch.stack(stats).mean(0).tolist() if stats else [0.0] * 3
        return {"disc/loss": loss_mean, "disc/acc_agent": acc_agent, "disc/acc_expert": acc_expert,
                "disc/accuracy": 0.5 * (acc_agent + acc_expert)}

    def step(self, x_agent: torch.Tensor, x_expert: torch.Tensor, mix: torch.Tensor,
             grad_penalty: float) -> torch.Tensor:
        if not self.regularised:
            return self.penalty_step(x_agent, x_expert, mix, grad_penalty)
        loss, parts = self._loss(x_agent, x_expert)
        penalty = loss.new_zeros(())
        if grad_penalty > 0 and len(mix):
            penalty = self._penalty(mix)
            loss = loss + grad_penalty * penalty
        self.optimizer.zero_grad(set_to_none=True)
        loss.backward()
        self.optimizer.step()
        return torch.cat([parts, penalty.detach()[None]])

    # ----------------------------------------------------------------------------- episodes (none needed)
    def observe(self, idx: Any, obs_n: torch.Tensor, codes: torch.Tensor, done: Any) -> None:
        pass

    def flush(self) -> None:
        pass

    def scalars(self) -> dict[str, float]:
        return {}

    # ------------------------------------------------------------------------------------------ checkpoints
    def state_dict(self) -> dict[str, Any]:
        return {"disc": self.disc.state_dict(), "disc_optimizer": self.optimizer.state_dict()}

    def load_state_dict(self, state: dict[str, Any]) -> None:
        self.disc.load_state_dict(state["disc"])
        self.optimizer.load_state_dict(state["disc_optimizer"])
