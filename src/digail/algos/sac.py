"""Soft actor-critic (Haarnoja et al. 2018) on the code-conditioned policy pi(a | s, c): the pure update.

`SACUpdate` holds the twin critics Q(s, c, a) with Polyak-averaged targets and the entropy temperature, and updates
them and the policy on a ready batch; the env loop, the replay buffer and the update schedule are the trainer's
`sac` learner (`digail.algos.learners.sac`).

Conventions (written out because each could be read two ways):

- The policy is the project's `SubtaskPolicy`: a Gaussian with a state-independent log-std, no tanh squashing, so
  that the VAE decoder initialises it as it does PPO's and a trained model evaluates as every other (its mean,
  clipped by the env). The critics, D and the replay buffer see the executed action (clipped to the bounds); the
  policy's gradient flows through that map (zero where a sample is clipped).
- The entropy term is the Gaussian's closed-form entropy H(pi(. | s, c)) = sum log std + A (1 + log 2 pi) / 2,
  the expectation of -log pi(a | s, c) that SAC estimates from one sample; it does not depend on the state.
- Critic target: y = r + gamma * [min_i Q'_i(s', c', a') + alpha H] with a' ~ pi(. | s', c') for a transition
  that continues or ends by a time limit; for one that ends by termination y = r + gamma * V_abs, where V_abs =
  r(absorbing) / (1 - gamma) is the value of staying in the absorbing state forever (its reward from D, no
  entropy, no bonus), or 0 without absorbing states.
- r is the trainer's reward of the sampled transition (D's reward + the directed-info bonus), relabelled with the
  current D; c' for the bootstrap target is the code the macro-policy chose for s' (`digail.algos.learners.sac`).
- Update order per step: critics (with the current alpha), policy (against the just-updated critics), alpha,
  then the target critics.
"""

from __future__ import annotations

import copy
import math
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import numpy as np
import torch

from digail.algos.optim import adam
from digail.config import SACConfig
from digail.errors import UserError
from digail.nets.policy import LOG_2PI, SubtaskPolicy
from digail.nets.twin_q import TwinQ


@dataclass(frozen=True)
class SACBatch:
    """B sampled transitions, ready for `SACUpdate.update`."""

    obs: torch.Tensor
    """(B, obs_dim) normalised s"""
    code_1h: torch.Tensor
    """(B, K) one-hot c (the code pi acted on)"""
    acts: torch.Tensor
    """(B, A) executed a"""
    next_obs: torch.Tensor
    """(B, obs_dim) normalised s' (the final observation where an episode ended)"""
    next_code_1h: torch.Tensor
    """(B, K) one-hot c' (the code chosen for s' in the rollout)"""
    terminated: torch.Tensor
    """(B,) bool: the episode ended by termination at s'"""
    rews: torch.Tensor
    """(B,) the reward r of the transition (D's reward plus the bonus)"""
    absorbing_value: torch.Tensor
    """() V_abs, the value of the absorbing state that follows a termination (0: no absorbing states)"""


class SACUpdate:
    """The soft actor-critic update on `pi` (trained in place) with its own twin critics, targets and temperature.

    Args:
        pi: the Gaussian sub-task policy.
        obs_dim: observation size.
        codes: K.
        cfg: SAC settings.
        to_env: sampled actions -> executed actions (torch; the clip to the bounds), differentiable.
        device: where the critics live.
        bc: optional () -> BC loss on expert pairs and its weight, added to the policy's loss (the +L2 methods).
        bounds: the (low, high) action bounds when `to_env` is the clip to them: the update then runs the
            hand-written gradients of `digail.algos.fast.sac_grad` (without a BC term), else autograd.
        zero_code_weights: start the critics with zero weights on the code inputs (`TrainConfig.zero_code_weights`).
    """

    def __init__(self, pi: SubtaskPolicy, obs_dim: int, codes: int, cfg: SACConfig,
                 to_env: Callable[[torch.Tensor], torch.Tensor], device: torch.device,
                 bc: tuple[Callable[[], torch.Tensor], float] | None = None,
                 bounds: tuple[np.ndarray, np.ndarray] | None = None, zero_code_weights: bool = False) -> None:
        if pi.action.discrete:
            raise UserError("--train.learner sac needs continuous actions; use --train.learner ppo for this env.")
        self.pi, self.cfg, self.to_env, self.bc = pi, cfg, to_env, bc
        self.act_dim = pi.action.dim
        self.critic = TwinQ(obs_dim, codes, self.act_dim, cfg.hidden).to(device)
        if zero_code_weights:
            self.critic.zero_code_weights()
        self.critic_target = copy.deepcopy(self.critic).requires_grad_(False)
        self.log_alpha = torch.tensor(math.log(cfg.init_alpha), device=device, requires_grad=cfg.learn_alpha)
        self.target_entropy = -float(self.act_dim) if cfg.target_entropy is None else cfg.target_entropy
        self.pi_params = [p for p in pi.parameters() if p.requires_grad]
        self.q_optimizer = adam(list(self.critic.parameters()), lr=cfg.lr)
        self.pi_optimizer = adam(self.pi_params, lr=cfg.effective_policy_lr)
        self.alpha_optimizer = adam([self.log_alpha], lr=cfg.alpha_lr)
        self._q_params: list[torch.Tensor] = list(self.critic.parameters())
        self._target_params: list[torch.Tensor] = list(self.critic_target.parameters())
        from digail.algos.fast.mlp import plain_layers

        pi_lin = plain_layers(pi.net)
        from digail.algos import fast

        self.hand = fast.enabled() and bounds is not None and bc is None and pi_lin is not None and all(
            p.requires_grad for p in pi.parameters())
        """whether `update` runs the hand-written gradients"""
        if self.hand:
            assert bounds is not None and pi_lin is not None
            self._low, self._high = (torch.as_tensor(np.asarray(v, np.float32), device=device) for v in bounds)
            self._pi_w, self._pi_b = [m.weight for m in pi_lin], [m.bias for m in pi_lin]
            self._pi_targets = [*self._pi_w, *self._pi_b, pi.log_std]
            n = len(self.critic.weights)
            self._q_w, self._q_b = self._q_params[:n], self._q_params[n:]
            self._t_w, self._t_b = self._target_params[:n], self._target_params[n:]
            from digail.algos.fast.step import FusedAdamState

            self._q_adam = FusedAdamState(self.q_optimizer, self._q_params)
            self._pi_adam = FusedAdamState(self.pi_optimizer, self._pi_targets)
            self._alpha_params = [self.log_alpha]
            self._alpha_adam = FusedAdamState(self.alpha_optimizer, self._alpha_params)
        self.fused_updates = 0
        """updates run as one scripted call (`digail.algos.fast.sac_grad.sac_update`)"""

    def entropy(self) -> torch.Tensor:
        """H(pi(. | s, c)), the same for every state (state-independent log-std)."""
        ls = self.pi.log_std.clamp(-5.0, 2.0)
        return ls.sum() + 0.5 * self.act_dim * (1.0 + LOG_2PI)

    def _sample(self, obs: torch.Tensor, code_1h: torch.Tensor, noise: torch.Tensor) -> torch.Tensor:
        """Executed actions to_env(mean + std * noise) of pi at (s, c), differentiable in pi's parameters."""
        mean = self.pi.net(self.pi.inputs(obs, code_1h))
        return self.to_env(mean + self.pi.log_std.clamp(-5.0, 2.0).exp() * noise)

    def update(self, b: SACBatch, noise_next: torch.Tensor, noise_pi: torch.Tensor,
               train_policy: bool = True) -> torch.Tensor:
        """One update of the critics, the policy, alpha and the targets; `noise_*` (B, A) are the standard normals
        of a' ~ pi(. | s', c') and of the policy's reparameterised actions; `train_policy` False leaves pi and
        alpha as they are (the losses are still computed and returned). Returns the detached
        [critic loss, policy loss, alpha loss, alpha, entropy, mean Q, BC loss] (no host sync)."""
        gamma = self.cfg.gamma
        if self.hand:
            return self._update_hand(b, noise_next, noise_pi, train_policy)
        alpha = self.log_alpha.detach().exp()
        with torch.no_grad():
            entropy = self.entropy()
            next_acts = self._sample(b.next_obs, b.next_code_1h, noise_next)
            q_next = self.critic_target(torch.cat([b.next_obs, b.next_code_1h, next_acts], -1)).min(0).values
            v_next = torch.where(b.terminated, b.absorbing_value, q_next + alpha * entropy)
            target = b.rews + gamma * v_next
        q = self.critic(torch.cat([b.obs, b.code_1h, b.acts], -1))
        q_loss = 0.5 * (q - target).pow(2).mean(1).sum()
        self.q_optimizer.zero_grad(set_to_none=True)
        q_loss.backward()
        self.q_optimizer.step()

        # the policy against the updated critics; only pi's gradients are computed (the critics' are not needed)
        acts = self._sample(b.obs, b.code_1h, noise_pi)
        q_pi = self.critic(torch.cat([b.obs, b.code_1h, acts], -1)).min(0).values
        entropy = self.entropy()
        pi_loss = -q_pi.mean() - alpha * entropy
        bc_value = torch.zeros((), device=q.device)
        if self.bc is not None:
            bc_fn, weight = self.bc
            bc_value = bc_fn()
            pi_loss = pi_loss + weight * bc_value
        if train_policy:
            grads = torch.autograd.grad(pi_loss, self.pi_params)
            for p, g in zip(self.pi_params, grads, strict=True):
                p.grad = g
            self.pi_optimizer.step()

        alpha_loss = self._alpha_and_targets(entropy.detach(), train_policy)
        return torch.stack([q_loss.detach(), pi_loss.detach(), alpha_loss, alpha, entropy.detach(),
                            q.detach().mean(), bc_value.detach()])

    def _alpha_and_targets(self, entropy: torch.Tensor, train_policy: bool) -> torch.Tensor:
        """The temperature's step and the targets' Polyak step; returns the temperature's loss."""
        # alpha: d/d log_alpha of log_alpha * (H - H_target), so alpha falls while the entropy is above its target
        alpha_loss = self.log_alpha.detach() * (entropy - self.target_entropy)
        if self.cfg.learn_alpha and train_policy:
            self.log_alpha.grad = (entropy - self.target_entropy).reshape(())
            self.alpha_optimizer.step()
        with torch.no_grad():
            for target, source in zip(self._target_params, self._q_params, strict=True):
                target.lerp_(source, self.cfg.tau)
        return alpha_loss

    @torch.no_grad()
    def _update_hand(self, b: SACBatch, noise_next: torch.Tensor, noise_pi: torch.Tensor,
                     train_policy: bool) -> torch.Tensor:
        """`update` with the gradients of `digail.algos.fast.sac_grad`: the same steps in the same order, as one
        scripted call (`sac_update`) once the optimisers hold their state (torch's own first steps create it)."""
        from digail.algos.fast.sac_grad import sac_update
        from digail.algos.fast.scripting import scripted

        unused: tuple[list[list[torch.Tensor]], list[float]] = ([], [])
        q_adam = self._q_adam.lists()
        pi_adam = self._pi_adam.lists() if train_policy else unused
        alpha_adam = self._alpha_adam.lists() if train_policy and self.cfg.learn_alpha else unused
        if q_adam is None or pi_adam is None or alpha_adam is None:
            return self._update_hand_steps(b, noise_next, noise_pi, train_policy)
        pi = self.pi
        obs_code = torch.cat([b.obs, b.code_1h], -1)
        next_obs_code = torch.cat([b.next_obs, b.next_code_1h], -1)
        plain = pi.decoder_obs is None  # pi's inputs are [s, c] as the critics'
        self.fused_updates += 1
        return scripted(sac_update)(
            torch.cat([obs_code, b.acts], -1), next_obs_code if plain else pi.inputs(b.next_obs, b.next_code_1h),
            next_obs_code, obs_code if plain else pi.inputs(b.obs, b.code_1h), obs_code, noise_next, noise_pi,
            b.terminated, b.rews, b.absorbing_value, self.cfg.gamma, self.cfg.tau, self.target_entropy, self._low,
            self._high, self._pi_targets, self._q_params, self._target_params, self._alpha_params, *q_adam, *pi_adam,
            *alpha_adam, train_policy, self.cfg.learn_alpha)

    def _update_hand_steps(self, b: SACBatch, noise_next: torch.Tensor, noise_pi: torch.Tensor,
                           train_policy: bool) -> torch.Tensor:
        """`_update_hand` in pieces, with the optimisers' own steps (which create their state)."""
        from digail.algos.fast.sac_grad import critic_grads, policy_grads
        from digail.algos.fast.scripting import scripted

        pi = self.pi
        alpha = self.log_alpha.detach().exp()
        entropy = self.entropy()
        std = pi.log_std.clamp(-5.0, 2.0).exp()
        next_obs_code = torch.cat([b.next_obs, b.next_code_1h], -1)
        grads, q_loss, q_mean = scripted(critic_grads)(
            torch.cat([b.obs, b.code_1h, b.acts], -1), pi.inputs(b.next_obs, b.next_code_1h), next_obs_code,
            noise_next, b.terminated, b.rews, b.absorbing_value, alpha, entropy, self.cfg.gamma, self._low,
            self._high, self._pi_w, self._pi_b, std, self._q_w, self._q_b, self._t_w, self._t_b)
        for p, g in zip(self._q_params, grads, strict=True):
            p.grad = g
        self.q_optimizer.step()
        pi_grads, pi_loss = scripted(policy_grads)(
            pi.inputs(b.obs, b.code_1h), torch.cat([b.obs, b.code_1h], -1), noise_pi, alpha, entropy, self._low,
            self._high, self._pi_w, self._pi_b, pi.log_std, self._q_w, self._q_b)
        if train_policy:
            for p, g in zip(self._pi_targets, pi_grads, strict=True):
                p.grad = g
            self.pi_optimizer.step()
        alpha_loss = self._alpha_and_targets(entropy, train_policy)
        return torch.stack([q_loss, pi_loss, alpha_loss, alpha, entropy, q_mean, torch.zeros_like(q_loss)])

    STAT_NAMES = ("losses/critic", "losses/policy", "losses/alpha", "sac/alpha", "sac/entropy", "sac/q", "losses/bc")

    def state_dict(self) -> dict[str, Any]:
        return {"critic": self.critic.state_dict(), "critic_target": self.critic_target.state_dict(),
                "log_alpha": self.log_alpha.detach().clone(), "q_optimizer": self.q_optimizer.state_dict(),
                "pi_optimizer": self.pi_optimizer.state_dict(), "alpha_optimizer": self.alpha_optimizer.state_dict()}

    def load_state_dict(self, state: dict[str, Any]) -> None:
        self.critic.load_state_dict(state["critic"])
        self.critic_target.load_state_dict(state["critic_target"])
        with torch.no_grad():
            self.log_alpha.copy_(state["log_alpha"])
        self.q_optimizer.load_state_dict(state["q_optimizer"])
        self.pi_optimizer.load_state_dict(state["pi_optimizer"])
        self.alpha_optimizer.load_state_dict(state["alpha_optimizer"])
