"""The discriminator's updates: binary cross-entropy of D(s, a) with the expert labelled 1 (`logits_expert_is_high`).

`discriminator_update` runs passes of minibatches over an on-policy rollout (PPO's iteration); `PenaltyStep` is one
step on replayed pairs with DAC's gradient penalty (SAC's, interleaved with the env steps).
"""

from __future__ import annotations

import importlib
from collections.abc import Callable

import numpy as np
import torch
from torch import nn

from digail.algos import fast
from digail.algos.fast.mlp import plain_layers
from digail.algos.fast.step import FusedAdamState
from digail.algos.ppo import maybe_compiled
from digail.errors import UserError
from digail.nets.critic import Discriminator
from digail.nets.normalizer import ObsNormalizer


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


class ObsView(nn.Module):
    """The part of a normalised observation D sees: `fn` of the raw observation (the normaliser undone), normalised
    again on the demonstrations' values of it.

    Args:
        fn: raw observations (n, D) -> D's features (n, F), torch in and out (an env's `relative_view`).
        normalizer: the policy's fixed observation normaliser, whose statistics it undoes.
        demo_obs: (M, D) raw demonstration observations, which set the features' statistics.
    """

    mean: torch.Tensor
    std: torch.Tensor

    def __init__(self, fn: Callable[[torch.Tensor], torch.Tensor], normalizer: ObsNormalizer,
                 demo_obs: np.ndarray) -> None:
        super().__init__()
        self.fn = fn
        self.register_buffer("mean", normalizer.mean.detach().clone().cpu())
        self.register_buffer("std", normalizer.std.detach().clone().cpu())
        with torch.no_grad():
            feats = _checked_features(fn, torch.as_tensor(np.asarray(demo_obs, np.float32)))
        self.out = ObsNormalizer(feats.shape[1]).fit(feats.numpy())
        self.dim = int(feats.shape[1])
        """F, the features D sees in place of the observation"""

    def forward(self, obs_n: torch.Tensor) -> torch.Tensor:
        name = getattr(self.fn, "__qualname__", repr(self.fn))
        try:
            feats = self.fn(obs_n * self.std + self.mean)
        except (Exception, SystemExit) as exc:  # noqa: BLE001  (the user's function: whatever it raises, one answer)
            raise UserError(f"D's view {name} fails on observations met during training ({type(exc).__name__}: "
                            f"{str(exc).strip()[:120]}); it must map every observation the env gives.") from None
        # the agent's observations are not the ones checked at the start: a view that changes width would be
        # broadcast against the demonstrations' statistics, and NaN would reach D's loss as a "non-finite loss"
        if not (isinstance(feats, torch.Tensor) and feats.shape == (obs_n.shape[0], self.dim)):
            got = tuple(feats.shape) if isinstance(feats, torch.Tensor) else type(feats).__name__
            raise UserError(f"D's view {name} returned {got} for {tuple(obs_n.shape)} observations during training "
                            f"after {self.dim} features per step on the demonstrations at the start; it must give the "
                            "same number of features for every observation.")
        if not torch.isfinite(feats).all():
            raise UserError(f"D's view {name} gives NaN or infinite features on observations met during training "
                            "(the demonstrations' were finite at the start); make it finite for every observation the "
                            "env can give.")
        return self.out(feats.float())


def _checked_features(fn: Callable[[torch.Tensor], torch.Tensor], obs: torch.Tensor) -> torch.Tensor:
    """`fn(obs)`, refused in one sentence unless it is a finite float tensor with a row per observation."""
    name = getattr(fn, "__qualname__", repr(fn))
    try:
        feats = fn(obs)
    except (Exception, SystemExit) as exc:  # noqa: BLE001  (the user's function: whatever it raises, one answer)
        raise UserError(f"D's view {name} fails on the demonstrations' observations ({type(exc).__name__}: "
                        f"{str(exc).strip()[:120]}); it must map a float tensor (n, D) to features (n, F).") from None
    if not (isinstance(feats, torch.Tensor) and feats.dim() == 2 and feats.shape[0] == obs.shape[0]
            and feats.shape[1] >= 1 and feats.is_floating_point()):
        got = tuple(feats.shape) if isinstance(feats, torch.Tensor) else type(feats).__name__
        raise UserError(f"D's view {name} returned {got} for {tuple(obs.shape)} observations; it must return a "
                        "float tensor with one row of features per observation, (n, F).")
    if not torch.isfinite(feats).all():
        raise UserError(f"D's view {name} gives NaN or infinite features on the demonstrations; make it finite.")
    return feats.float()


SHIPPED_VIEWS = frozenset({"digail.envs.fetch:placing_view", "digail.envs.fetch:distances_view",
                           "digail.envs.fetch:log_distances_view"})
"""`module:function` views that digail itself ships beside the envs' relative views: a run folder that records one
names no code of the user's, so resuming it needs no `--train.disc-obs`"""


def obs_view(env_id: str, kind: str, normalizer: ObsNormalizer, demo_obs: np.ndarray) -> ObsView | None:
    """D's view of the observation for `--train.disc-obs kind`: None for `all`, the env's relative view for
    `relative`, or the user's function for `module:function`."""
    if kind == "all":
        return None
    if kind == "relative":
        from digail.envs.registry import env_spec

        spec = env_spec(env_id)
        if spec is None or spec.relative_view is None:
            raise UserError(f"{env_id} has no relative view of its observation for D; use --train.disc-obs all, or "
                            "write one and pass it as --train.disc-obs module:function.")
        module, _, name = spec.relative_view.partition(":")
        return ObsView(getattr(importlib.import_module(module), name), normalizer, demo_obs)
    from digail.user_envs import import_function

    return ObsView(import_function(kind, "--train.disc-obs"), normalizer, demo_obs)


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
