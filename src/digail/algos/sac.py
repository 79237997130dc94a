"""Soft actor-critic (Haarnoja et al. 2018) on the code-conditioned policy pi(a | s, c): the off-policy learner.

`SACLearner` is the pure update (twin critics Q(s, c, a) with Polyak-averaged targets, the policy, the entropy
temperature); `OffPolicyLoop` is what `GAIL` runs per iteration when `TrainConfig.learner` is "sac": step the
envs with the current policy, store every transition in the replay buffer, update D on replayed agent pairs
against the expert's (with DAC's gradient penalty and absorbing states, Kostrikov et al. 2019), and update SAC on
sampled batches whose reward is relabelled with the current D.

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
- r = D's reward (`reward_fn`, default `generator_reward(logits, TrainConfig.reward)`) + lambda_1 * the stored
  directed-info bonus log q(c' | s', c) (+ lambda_1 log K with `bonus_code_entropy`), as for PPO.
- c' for the bootstrap target is the code the macro-policy chose for s' during the rollout (stored with the
  transition): a sample of q (or argmax, `closed_loop_codes`), or the replayed expert code in expert-replay envs,
  chosen on the final observation where an episode ended. It is the code pi acted on at s', so the target follows
  the hierarchical policy that collected the data, and q runs once per env step, never per sampled batch.
- Update order per step: critics (with the current alpha), policy (against the just-updated critics), alpha,
  then the target critics.
"""

from __future__ import annotations

import copy
import math
import time
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import numpy as np
import torch

from digail.algos.aux_losses import bc_loss
from digail.algos.discriminator import disc_loss
from digail.algos.optim import adam
from digail.algos.replay import ReplayBuffer
from digail.config import SACConfig
from digail.data.trajectory import Trajectory
from digail.errors import TrainingError, UserError
from digail.nets.critic import Discriminator
from digail.nets.policy import LOG_2PI, SubtaskPolicy
from digail.nets.twin_q import TwinQ
from digail.utils import keep_heap_pages


@dataclass(frozen=True)
class SACBatch:
    """B sampled transitions, ready for `SACLearner.update`."""

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


class SACLearner:
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
        from digail.algos.fast.ppo_grad import plain_mlp_layers

        pi_lin = plain_mlp_layers(pi.net)
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
            torch._foreach_lerp_(self._target_params, self._q_params, self.cfg.tau)
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


class OffPolicyLoop:
    """The `sac` learner of a `GAIL` / `DirectedInfoGAIL` trainer: its env loop, replay buffer, D and SAC updates.

    It uses the trainer's envs, codes (`choose_codes`, `start_episodes`), policy, expert data, reward function and
    generators, and replaces the trainer's D by one that also sees an absorbing-state flag (with
    `SACConfig.absorbing`). One iteration is `steps_per_iteration` env steps.
    """

    def __init__(self, trainer: Any, demos: list[Trajectory]) -> None:  # a GAIL trainer; gail.py imports this module
        t = trainer
        self.t, self.cfg = t, t.cfg.sac
        if t.discrete:
            raise UserError("--train.learner sac needs continuous actions; use --train.learner ppo for this env.")
        if t.cfg.anchor_weight > 0:
            raise UserError("--train.anchor-weight is a PPO term; set it to 0 with --train.learner sac (the BC term, "
                            "--bc-weight, works with both).")
        obs_dim, act_dim = t.model.obs_dim, t.model.action.dim
        self.obs_dim, self.act_dim = obs_dim, act_dim
        pi = t.model.pi
        bc = None
        if t.cfg.bc_weight > 0:
            bc = (lambda: bc_loss(pi, t.expert, t.eye, t.cfg.bc_batch_size, t.gen, discrete=False), t.cfg.bc_weight)
        space: Any = t.envs.probe.action_space
        clip = getattr(t.envs.probe.unwrapped, "canonical_action", None) is None  # `env_action_fn`'s rule
        bounds = (space.low, space.high) if clip else None
        self.learner = SACLearner(pi, obs_dim, t.K, self.cfg, t._to_env_actions, t.device, bc=bc, bounds=bounds,
                                  zero_code_weights=t.cfg.zero_code_weights)
        self.flag = 1 if self.cfg.absorbing else 0
        if self.cfg.absorbing:  # D sees [obs, absorbing flag, action]
            t.disc = Discriminator(obs_dim + 1, act_dim, t.cfg.hidden).to(t.device)
            t.disc_optimizer = adam(list(t.disc.parameters()), lr=t.cfg.disc_lr)
        expert_in = t.expert.disc_in
        if self.cfg.absorbing:
            zeros = expert_in.new_zeros(len(expert_in), 1)
            expert_in = torch.cat([expert_in[:, :obs_dim], zeros, expert_in[:, obs_dim:]], -1)
            ends = sum(bool(d.terminated) for d in demos)  # one absorbing row per demonstration that terminated
            expert_in = torch.cat([expert_in, self.absorbing_row().expand(ends, -1)])
        self.expert_in = expert_in
        """D's expert inputs: every demonstration step, and the absorbing state once per terminated demonstration"""
        self.buffer = ReplayBuffer(self.cfg.buffer_size, obs_dim, act_dim, t.K, t.device)
        if t.device.type == "cpu":
            keep_heap_pages()  # each update's temporaries would otherwise be page-faulted in anew
        self._update_debt = 0.0
        self._disc_debt = 0
        self.updates = 0
        """SAC updates so far"""
        from digail.algos import fast
        from digail.algos.fast.inference import LivePolicy

        # pi's mean action read from its live weights in NumPy on the fast path; its module on the reference
        self.live = LivePolicy(pi, obs_dim) if t.device.type == "cpu" and fast.enabled() else None
        from digail.algos.fast.ppo_grad import plain_mlp_layers

        d_lin = plain_mlp_layers(t.disc.net)
        self.hand_disc = fast.enabled() and d_lin is not None
        """whether D's step runs the hand-written gradient of `digail.algos.fast.sac_grad.disc_grads`"""
        self._d_w = [m.weight for m in d_lin or []]
        self._d_b = [m.bias for m in d_lin or []]
        self._d_params = [*self._d_w, *self._d_b]
        from digail.algos.fast.step import FusedAdamState

        self._d_adam = FusedAdamState(t.disc_optimizer, self._d_params)
        self._v_abs: torch.Tensor | None = None
        """V_abs for the current D (None: to be computed); D's step and a checkpoint's load reset it"""
        self._sac_stats: list[torch.Tensor] = []
        self._disc_stats: list[torch.Tensor] = []
        self._t_env = 0.0

    def absorbing_row(self) -> torch.Tensor:
        """D's input (1, obs_dim + 1 + A) for the absorbing state: zero observation and action, flag 1."""
        row = torch.zeros(1, self.obs_dim + 1 + self.act_dim, device=self.t.device)
        row[0, self.obs_dim] = 1.0
        return row

    # ---------------------------------------------------------------------------------------------- acting
    def _mean_actions(self, obs_n: np.ndarray, codes: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        if self.live is not None:
            return self.live(obs_n, codes), self.live.std()
        pi, t = self.t.model.pi, self.t
        with torch.no_grad():
            obs = torch.from_numpy(obs_n).to(t.device)
            mean = pi.net(pi.inputs(obs, t.eye[torch.from_numpy(codes).to(t.device)]))
            return mean.cpu().numpy(), pi.log_std.clamp(-5.0, 2.0).exp().cpu().numpy()

    def _env_step(self) -> None:
        """One step of every env with the current policy; the transitions go into the buffer."""
        t = self.t
        assert t.rollout_state is not None
        st = t.rollout_state
        cstate, n = st.code_state, t.envs.num_envs
        all_idx = np.arange(n)
        normalize = self._normalize
        mean, std = self._mean_actions(st.obs_n, st.codes)
        acts = mean + std * t.np_rng.standard_normal(mean.shape, dtype=np.float32)
        executed = np.asarray(t._env_actions(acts), dtype=np.float32)
        next_obs, rews, terms, truncs, _, final = t.envs.step(executed)
        st.ep_returns += rews
        st.ep_lengths += 1
        cstate.t_ep += 1
        next_n = normalize(next_obs)
        prev = cstate.prev
        if final:
            done = np.fromiter(final, dtype=np.int64, count=len(final))
            stored_next = next_n.copy()
            stored_next[done] = normalize(np.stack([final[i][0] for i in done]))
            # c' and the bonus are q's on the state the step produced: the final observation where an episode ended
            next_codes, bonus = t.choose_codes(stored_next, prev, cstate.t_ep, all_idx)
            stored_codes = next_codes.copy()
            for i in done:
                t._episode_done(int(i))
                st.ep_returns[i] = 0.0
                st.ep_lengths[i] = 0
            t.start_episodes(done)
            next_codes[done], _ = t.choose_codes(next_n[done], prev[done], cstate.t_ep[done], done)
        else:
            next_codes, bonus = t.choose_codes(next_n, prev, cstate.t_ep, all_idx)
            stored_next, stored_codes = next_n, next_codes
        self.buffer.add(obs=st.obs_n, codes=st.codes, acts=executed, next_obs=stored_next, next_codes=stored_codes,
                        terminated=terms, bonus=bonus, rews=rews)
        prev[:] = next_codes
        st.obs_n, st.codes = next_n, next_codes
        t.global_step += n

    # --------------------------------------------------------------------------------------------- updates
    def _disc_inputs(self, b: dict[str, torch.Tensor]) -> torch.Tensor:
        parts = [b["obs"]]
        if self.cfg.absorbing:
            parts.append(b["obs"].new_zeros(len(b["obs"]), 1))
        return torch.cat([*parts, b["acts"]], -1)

    def _disc_logits(self, x: torch.Tensor) -> torch.Tensor:
        """D's logits (n,) for its inputs x (n, .)."""
        if self.hand_disc:
            from digail.algos.fast.sac_grad import mlp_out
            from digail.algos.fast.scripting import scripted

            return scripted(mlp_out)(x, self._d_w, self._d_b).squeeze(-1)
        return self.t.disc.net(x).squeeze(-1)

    def update_discriminator(self) -> torch.Tensor:
        """One Adam step of D on half a minibatch of replayed agent pairs (label 0; with absorbing states, the
        absorbing state once for each of them that terminated) and as many expert pairs (label 1), plus the
        gradient penalty. Returns the detached [loss, agent accuracy, expert accuracy, penalty]."""
        t = self.t
        half = max(1, t.cfg.disc_minibatch_size // 2)
        b = self.buffer.get(self.buffer.sample_indices(half, t.gen))
        x_agent = self._disc_inputs(b)
        if self.cfg.absorbing:
            x_agent = torch.cat([x_agent, self.absorbing_row().expand(int(b["terminated"].sum()), -1)])
        x_expert = self.expert_in[torch.randint(len(self.expert_in), (half,), generator=t.gen, device="cpu")]
        mix = x_expert[:0]
        if self.cfg.grad_penalty > 0:
            eps = torch.rand(half, 1, generator=t.gen).to(t.device)
            mix = eps * x_expert + (1 - eps) * x_agent[:half]
        self._v_abs = None
        adam = self._d_adam.lists() if self.hand_disc else None
        if adam is not None:
            from digail.algos.fast.sac_grad import disc_update
            from digail.algos.fast.scripting import scripted

            with torch.no_grad():
                return scripted(disc_update)(x_agent, x_expert, mix, self._d_params, float(self.cfg.grad_penalty),
                                             *adam)
        if self.hand_disc:  # until D's optimiser holds its state (its own first step creates it)
            from digail.algos.fast.sac_grad import disc_grads
            from digail.algos.fast.scripting import scripted

            with torch.no_grad():
                grads, parts = scripted(disc_grads)(x_agent, x_expert, mix, self._d_w, self._d_b,
                                                    float(self.cfg.grad_penalty))
            for p, g in zip(self._d_params, grads, strict=True):
                p.grad = g
            t.disc_optimizer.step()
            return parts
        loss, parts = disc_loss(t.disc, x_agent, x_expert)
        penalty = loss.new_zeros(())
        if self.cfg.grad_penalty > 0:
            mix = mix.requires_grad_(True)
            (g,) = torch.autograd.grad(t.disc.net(mix).sum(), mix, create_graph=True)
            penalty = (g.norm(dim=1) - 1.0).pow(2).mean()
            loss = loss + self.cfg.grad_penalty * penalty
        t.disc_optimizer.zero_grad(set_to_none=True)
        loss.backward()
        t.disc_optimizer.step()
        return torch.cat([parts, penalty.detach()[None]])

    def rewards(self, b: dict[str, torch.Tensor]) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        """The sampled transitions' reward relabelled with the current D (plus the bonus), D's part of it, and V_abs."""
        t = self.t
        with torch.no_grad():
            disc_rew = t.reward_fn(self._disc_logits(self._disc_inputs(b)), b)
            bonus = t.cfg.bonus_weight * b["bonus"]
            if t.cfg.bonus_code_entropy and t.K > 1:
                bonus = bonus + t.cfg.bonus_weight * math.log(t.K)
            if self._v_abs is None:
                self._v_abs = torch.zeros((), device=t.device)
                if self.cfg.absorbing:
                    r_abs = t.reward_fn(self._disc_logits(self.absorbing_row()), {"rews": torch.zeros(1)})
                    self._v_abs = r_abs.reshape(()) / (1.0 - self.cfg.gamma)
        return disc_rew + bonus, disc_rew, self._v_abs

    def update_policy(self) -> torch.Tensor:
        """One SAC update on a sampled batch; its stats and the batch's mean D reward."""
        t, B = self.t, self.cfg.batch_size
        b = self.buffer.get(self.buffer.sample_indices(B, t.gen))
        rews, disc_rew, v_abs = self.rewards(b)
        batch = SACBatch(obs=b["obs"], code_1h=b["code_1h"], acts=b["acts"], next_obs=b["next_obs"],
                         next_code_1h=b["next_code_1h"], terminated=b["terminated"], rews=rews,
                         absorbing_value=v_abs)
        noise = torch.randn(2, B, self.act_dim, generator=t.gen).to(t.device)
        stats = self.learner.update(batch, noise[0], noise[1], train_policy=self.updates >= self.cfg.policy_warmup)
        self.updates += 1
        return torch.cat([stats, disc_rew.mean()[None], v_abs[None]])

    # ------------------------------------------------------------------------------------------- iteration
    def step_and_update(self) -> None:
        """One step of every env, then its share of D updates (one per `disc_every` env steps) and SAC updates
        (`utd` per env step), once the buffer holds `learning_starts` transitions."""
        cfg, n = self.cfg, self.t.envs.num_envs
        t1 = time.perf_counter()
        self._env_step()
        self._t_env += time.perf_counter() - t1
        if self.buffer.size < max(cfg.learning_starts, 1):
            return
        if cfg.disc_every > 0:
            self._disc_debt += n
            while self._disc_debt >= cfg.disc_every:
                self._disc_debt -= cfg.disc_every
                self._disc_stats.append(self.update_discriminator())
        self._update_debt += n * cfg.utd
        while self._update_debt >= 1.0:
            self._update_debt -= 1.0
            self._sac_stats.append(self.update_policy())

    def _normalize(self, obs: np.ndarray) -> np.ndarray:
        return self._norm_fn(obs)

    def iterate(self) -> dict[str, float]:
        """One iteration: `steps_per_iteration` env steps, each followed by its share of D and SAC updates."""
        from digail.algos.inference import code_net

        t, cfg = self.t, self.cfg
        t0 = time.perf_counter()
        self._norm_fn = t.model.normalizer.numpy_fn()
        t._q_snap = code_net(t.model.q, t.model.obs_dim) if t.K > 1 else None  # q is frozen
        if t.rollout_state is None:
            t.rollout_state = t._reset_envs()
        n = t.envs.num_envs
        self._sac_stats, self._disc_stats, self._t_env = [], [], 0.0
        for _ in range(cfg.steps_per_env):
            self.step_and_update()
        sac_stats, disc_stats, t_env = self._sac_stats, self._disc_stats, self._t_env
        t._q_snap = None
        steps = cfg.steps_per_env * n
        out: dict[str, float] = {}
        if sac_stats:
            means = torch.stack(sac_stats).mean(0).tolist()
            out.update(zip((*SACLearner.STAT_NAMES, "rollout/disc_reward", "sac/absorbing_value"), means, strict=True))
        else:
            out.update({k: float("nan") for k in (*SACLearner.STAT_NAMES, "rollout/disc_reward",
                                                  "sac/absorbing_value")})
        if disc_stats:
            loss, acc_a, acc_e, gp = torch.stack(disc_stats).mean(0).tolist()
        else:
            loss = acc_a = acc_e = gp = float("nan")
        out.update({"disc/loss": loss, "disc/acc_agent": acc_a, "disc/acc_expert": acc_e,
                    "disc/accuracy": 0.5 * (acc_a + acc_e), "disc/grad_penalty": gp})
        checked = [k for k in out if (disc_stats if k.startswith("disc/") else sac_stats)]
        bad = [k for k in checked if not math.isfinite(out[k])]
        if bad:
            raise TrainingError(f"non-finite loss ({', '.join(bad)}) at iteration {t.iteration + 1}; the last "
                                "good checkpoint is kept - lower the learning rate or check the demonstrations.")
        t.iteration += 1
        elapsed = time.perf_counter() - t0
        recent = self.buffer.bonus[(self.buffer.pos - np.arange(1, min(steps, self.buffer.size) + 1))
                                   % self.buffer.capacity]
        out.update({
            "rollout/bonus": float(recent.mean()) if len(recent) else float("nan"),
            "rollout/ep_return": float(np.mean(t.recent_returns)) if t.recent_returns else float("nan"),
            "rollout/ep_length": float(np.mean(t.recent_lengths)) if t.recent_lengths else float("nan"),
            "rollout/ep_return_closed_loop": (float(np.mean(t.recent_closed_returns))
                                              if t.recent_closed_returns else float("nan")),
            "perf/sps": steps / elapsed,
            "perf/rollout_sps": steps / max(t_env, 1e-9),
            "perf/global_step": float(t.global_step),
            "sac/updates": float(len(sac_stats)),
        })
        return out

    # ------------------------------------------------------------------------------------------ checkpoints
    def state_dict(self) -> dict[str, Any]:
        return {"learner": self.learner.state_dict(), "buffer": self.buffer.state_dict(),
                "update_debt": self._update_debt, "disc_debt": self._disc_debt, "updates": self.updates}

    def load_state_dict(self, state: dict[str, Any]) -> None:
        self.learner.load_state_dict(state["learner"])
        self.buffer.load_state_dict(state["buffer"])
        self._v_abs = None
        self._update_debt = float(state["update_debt"])
        self._disc_debt = int(state["disc_debt"])
        self.updates = int(state["updates"])
