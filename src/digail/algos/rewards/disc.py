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
from collections.abc import Callable, Iterator
from typing import Any

import torch
from torch import nn

from digail.algos.optim import adam, check_finite
from digail.algos.rewards.base import EnvStep, RewardHost, Rollout, Steps
from digail.algos.rewards.discriminator import (
    Discriminator,
    PenaltyStep,
    disc_loss,
    discriminator_update,
    generator_reward,
)
from digail.algos.rewards.views import RewardInputs
from digail.errors import UserError
from digail.imitation_config import ImitationConfig


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
    """The discriminator D(s, a) (`logits_expert_is_high`) and its updates; it pays the host's `reward_fn` of D's
    logits (`--train.imitation.logits-to-reward` by default: -log(1 - D)).

    On-policy, each rollout gets `disc_updates` passes of minibatches; off-policy, one step on replayed agent pairs
    against as many expert pairs every `disc_every` env steps, with the gradient penalty on points between them.
    With the plain settings (`bce`, no regulariser) its updates are GAIL's as they always were (the on-policy
    passes of `discriminator_update`, the off-policy `PenaltyStep`, on the fast path where it runs); otherwise
    they run on autograd with the configured loss and regularisers.

    Args:
        host: the trainer (the generator, the settings, the reward of logits).
        inputs: D's input rows of the agent's and the demonstrations' steps.
        kind: `bce` (binary cross-entropy) or `pu` (positive-unlabeled).
    """

    def __init__(self, host: RewardHost, inputs: RewardInputs, kind: str = "bce") -> None:
        self.host, self.inputs, self.cfg, self.kind = host, inputs, host.cfg.imitation, kind
        if kind == "pu" and host.absorbing:
            raise UserError("--train.imitation.reward pu does not score absorbing states; drop --train.sac.absorbing "
                            "or use --train.imitation.reward bce.")
        self.pay: Callable[[torch.Tensor, dict[str, torch.Tensor]], torch.Tensor] = host.reward_fn or (
            lambda logits, batch: generator_reward(logits, self.cfg.logits_to_reward))
        """D's logits and their batch -> the policy's reward"""
        self.grad_penalty = host.cfg.effective_disc_grad_penalty
        """the weight of the gradient penalty on D (its default depends on the learner)"""
        obs_dim, act_dim = inputs.dims
        self.disc = Discriminator(obs_dim, act_dim, host.cfg.hidden).to(host.device)
        self.regularised = kind == "pu" or self.cfg.regularised
        """whether D's updates run the loss and regularisers on autograd instead of GAIL's plain steps"""
        if self.regularised:
            self.disc.net = regularised_net(obs_dim + act_dim, host.cfg.hidden, self.cfg, host.gen).to(host.device)
        self.optimizer = adam(list(self.disc.parameters()), lr=self.cfg.disc_lr)
        if self.cfg.disc_weight_decay > 0:
            for group in self.optimizer.param_groups:
                group["weight_decay"] = self.cfg.disc_weight_decay
        self.penalty_step = PenaltyStep(self.disc, self.optimizer)
        """D's plain off-policy step (and its logits), on the fast path where it runs"""
        self.debt = 0
        """off-policy: env steps towards D's next step"""
        self._rollout_stats: dict[str, float] | None = None
        self._step_stats: list[torch.Tensor] = []

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
        """D's logits (n,) for ready input rows x (`RewardInputs.rows`)."""
        if not self.regularised:
            return self.penalty_step.logits(x)
        with self._scoring():
            return self.disc.net(x).squeeze(-1)

    def rewards(self, steps: Steps) -> torch.Tensor:
        if steps.absorbing:
            return self.pay(self.logits(self.inputs.absorbing_row().expand(len(steps.obs), -1)), steps.batch)
        if steps.idx is not None:
            return self.pay(self.logits(self.inputs.rows(steps.obs, steps.acts)), steps.batch)
        T, N = steps.batch["logp"].shape
        with self._scoring():
            logits = self.disc.net(self.inputs.rows(steps.obs, steps.acts)).reshape(T, N)
        return self.pay(logits, steps.batch)

    # ---------------------------------------------------------------------------------------------- updates
    def update(self, agent: Rollout | EnvStep) -> None:
        if isinstance(agent, Rollout):
            self._rollout_stats = self._rollout_update(agent.steps, agent.compile)
            return
        every = self.cfg.disc_every
        if agent.sample is None or every <= 0:
            return
        self.debt += len(agent.done)
        while self.debt >= every:
            self.debt -= every
            self._step_stats.append(self._replay_step(agent.sample))

    def _loss(self, x_agent: torch.Tensor, x_expert: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """The configured loss on (noised) inputs, and the detached (loss, agent accuracy, expert accuracy)."""
        sigma = self.cfg.disc_noise
        if sigma > 0:
            x_agent = x_agent + sigma * torch.randn(x_agent.shape, generator=self.host.gen).to(x_agent)
            x_expert = x_expert + sigma * torch.randn(x_expert.shape, generator=self.host.gen).to(x_expert)
        if self.kind != "pu":
            return disc_loss(self.disc, x_agent, x_expert)
        logits_agent, logits_expert = self.disc.net(x_agent).squeeze(-1), self.disc.net(x_expert).squeeze(-1)
        loss = pu_loss(logits_agent, logits_expert, self.cfg.pu_prior)
        parts = torch.stack([loss, (logits_agent < 0).float().mean(), (logits_expert > 0).float().mean()])
        return loss, parts.detach()

    def _penalty(self, mix: torch.Tensor) -> torch.Tensor:
        mix = mix.requires_grad_(True)
        (g,) = torch.autograd.grad(self.disc.net(mix).sum(), mix, create_graph=True)
        return (g.norm(dim=1) - 1.0).pow(2).mean()

    def _rollout_update(self, steps: Steps, compile: bool) -> dict[str, float]:
        """`disc_updates` passes over a rollout's rows against the expert's; returns the `disc/*` scalars."""
        cfg, gen = self.cfg, self.host.gen
        x_agent, x_expert_all = self.inputs.rows(steps.obs, steps.acts), self.inputs.expert
        if not self.regularised:
            return discriminator_update(self.disc, self.optimizer, x_agent, x_expert_all, updates=cfg.disc_updates,
                                        minibatch_size=cfg.disc_minibatch_size, gen=gen, compile=compile,
                                        grad_penalty=self.grad_penalty)
        # the same passes and minibatches as `discriminator_update`, with the configured loss
        n = len(x_agent)
        half = max(1, min(cfg.disc_minibatch_size // 2, n))
        stats = []
        for _ in range(cfg.disc_updates):
            perm = torch.randperm(n, generator=gen)
            for start in range(0, n - half + 1, half):
                e_idx = torch.randint(len(x_expert_all), (half,), generator=gen)
                x_a, x_e = x_agent[perm[start:start + half]], x_expert_all[e_idx]
                loss, parts = self._loss(x_a, x_e)
                if self.grad_penalty > 0:
                    alpha = torch.rand(len(x_a), 1, generator=gen).to(x_a)
                    loss = loss + self.grad_penalty * self._penalty(alpha * x_a + (1 - alpha) * x_e)
                self.optimizer.zero_grad(set_to_none=True)
                loss.backward()
                self.optimizer.step()
                stats.append(parts)
        loss_mean, acc_agent, acc_expert = torch.stack(stats).mean(0).tolist() if stats else [0.0] * 3
        return {"disc/loss": loss_mean, "disc/acc_agent": acc_agent, "disc/acc_expert": acc_expert,
                "disc/accuracy": 0.5 * (acc_agent + acc_expert)}

    def _replay_step(self, sample: Callable[[int], Steps]) -> torch.Tensor:
        """One step of D on half a minibatch of replayed agent pairs (label 0; with absorbing states, the absorbing
        state once for each of them that terminated) and as many expert pairs (label 1), plus the gradient penalty.
        Returns the detached [loss, agent accuracy, expert accuracy, penalty]."""
        h, inputs = self.host, self.inputs
        half = max(1, self.cfg.disc_minibatch_size // 2)
        b = sample(half)
        x_agent = inputs.rows(b.obs, b.acts)
        if inputs.absorbing:
            x_agent = torch.cat([x_agent, inputs.absorbing_row().expand(int(b.batch["terminated"].sum()), -1)])
        x_expert = inputs.expert[torch.randint(len(inputs.expert), (half,), generator=h.gen, device="cpu")]
        mix = x_expert[:0]
        if self.grad_penalty > 0:
            eps = torch.rand(half, 1, generator=h.gen).to(h.device)
            mix = eps * x_expert + (1 - eps) * x_agent[:half]
        return self.step(x_agent, x_expert, mix, float(self.grad_penalty))

    def step(self, x_agent: torch.Tensor, x_expert: torch.Tensor, mix: torch.Tensor,
             grad_penalty: float) -> torch.Tensor:
        """One step of D on ready agent and expert rows with the gradient penalty on `mix` (empty without one);
        returns the detached [loss, agent accuracy, expert accuracy, penalty]."""
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

    def scalars(self) -> dict[str, float]:
        """`disc/*`: the last rollout's update, or the mean of D's off-policy steps since the last call (NaN before
        the first, placeholders rather than failures)."""
        if self._rollout_stats is not None:
            out, self._rollout_stats = self._rollout_stats, None
        else:
            stats, self._step_stats = self._step_stats, []
            loss, acc_a, acc_e, gp = torch.stack(stats).mean(0).tolist() if stats else [float("nan")] * 4
            out = {"disc/loss": loss, "disc/acc_agent": acc_a, "disc/acc_expert": acc_e,
                   "disc/accuracy": 0.5 * (acc_a + acc_e), "disc/grad_penalty": gp}
            if not stats:
                return out
        check_finite(out, self.host.iteration)
        return out

    # ------------------------------------------------------------------------------------------ checkpoints
    def state_dict(self) -> dict[str, Any]:
        return {"disc": self.disc.state_dict(), "disc_optimizer": self.optimizer.state_dict(), "disc_debt": self.debt}

    def load_state_dict(self, state: dict[str, Any]) -> None:
        self.disc.load_state_dict(state["disc"])
        self.optimizer.load_state_dict(state["disc_optimizer"])
        # checkpoints written before D kept its own schedule held the debt with the SAC learner's state
        self.debt = int(state.get("disc_debt", (state.get("offpolicy") or {}).get("disc_debt", 0)))
