"""PPO (Schulman et al., 2017) as the trainer's on-policy learner: the paper's.

Per iteration: roll out `steps_per_env` steps of every env (`collect_rollout`), hand the rollout to the reward to
learn from and pay, then GAE and the clipped update of pi and the value net V(s, c)
(`digail.algos.ppo`), optionally with the BC term and the anchor term.
"""

from __future__ import annotations

import copy
import time
from typing import Any

import torch

from digail.algos.aux_losses import anchor_loss, bc_loss
from digail.algos.learners.base import Host
from digail.algos.optim import adam, check_finite
from digail.algos.ppo import PPOBatch, compute_gae, ppo_update
from digail.algos.rewards.base import Rollout, Steps
from digail.algos.rollout import collect_rollout
from digail.errors import UserError
from digail.nets.critic import ValueNet


class PPOLearner:
    """PPO on pi(a | s, c) with its value net V(s, c) and one Adam over both (two groups: policy, value).

    Args:
        host: the trainer whose envs, codes and reward it uses.
    """

    def __init__(self, host: Host) -> None:
        self.host = host
        cfg = host.cfg
        model = host.model
        self.value = ValueNet(model.obs_dim, host.K, cfg.hidden).to(host.device)
        """V(s, c), the critic of GAE"""
        if cfg.zero_code_weights:
            self.value.zero_code_weights()
        self.optimizer = adam([{"params": list(model.pi.parameters()), "lr": cfg.ppo.effective_policy_lr},
                               {"params": list(self.value.parameters())}], lr=cfg.ppo.lr, eps=1e-5)
        if cfg.imitation.bc_schedule == "qfilter":
            raise UserError("--train.imitation.bc-schedule qfilter needs a critic of actions; use it with "
                            "--train.learner sac, or --train.imitation.bc-schedule anneal with PPO.")
        self.total_iterations = cfg.iterations
        """what `anneal_lr` decays over (`GAIL.train(iterations=...)` sets it)"""
        # a frozen copy of the initial policy for the anchor term (saved in checkpoints: resuming keeps the anchor)
        self.anchor_pi = copy.deepcopy(model.pi).requires_grad_(False) if cfg.anchor_weight > 0 else None

    @torch.no_grad()
    def collect(self) -> dict[str, torch.Tensor]:
        """One rollout of `steps_per_env` steps in every env (`collect_rollout`) as tensors on the device."""
        from digail.algos.inference import actor_critic

        h = self.host
        ac = actor_critic(h.model.pi, self.value, h.model.obs_dim)
        with h.frozen_codes():
            if h.rollout_state is None:
                h.rollout_state = h.reset_envs()
            # where each env's episode stands as the rollout starts (an episode-matching reward needs it)
            offsets = h.rollout_state.ep_lengths.copy()
            T = h.cfg.ppo.steps_per_env
            batch = collect_rollout(h.envs, ac, h.rollout_state, T, h.np_rng, normalize=h.model.normalizer.numpy_fn(),
                                    choose_codes=h.choose_codes, start_episodes=h.start_episodes,
                                    episode_done=h.episode_done, env_actions=h.env_actions)
        h.global_step += T * h.envs.num_envs
        batch["ep_offset"] = offsets
        return {k: torch.from_numpy(v).to(h.device) for k, v in batch.items()}

    def iterate(self) -> dict[str, float]:
        """Roll out, let the reward learn from the rollout and pay it, then the PPO update; returns the scalars."""
        h, cfg = self.host, self.host.cfg
        t0 = time.perf_counter()
        batch = self.collect()
        t_rollout = time.perf_counter() - t0
        T, N = batch["logp"].shape
        flat_obs = batch["obs"].reshape(T * N, -1)
        flat_acts = batch["acts"].reshape(T * N, *batch["acts"].shape[2:])
        steps = Steps(obs=flat_obs, acts=h.act_input(flat_acts), batch=batch)
        h.reward.update(Rollout(steps, compile=cfg.ppo.compile))
        stats = h.update_macro_policy(batch)
        with torch.no_grad():
            rews, disc_rew = h.with_bonus(h.reward.rewards(steps), batch)
        adv, returns = compute_gae(rews, batch["values"], batch["terminated"], batch["truncated"],
                                   batch["final_values"], batch["last_values"], cfg.ppo.gamma, cfg.ppo.gae_lambda)
        if cfg.ppo.anneal_lr:
            frac = max(0.0, 1.0 - h.iteration / max(self.total_iterations, 1))
            bases = (cfg.ppo.effective_policy_lr, cfg.ppo.lr)  # the optimiser's groups, in order
            for group, base in zip(self.optimizer.param_groups, bases, strict=True):
                group["lr"] = base * frac
        ppo_batch = PPOBatch(obs=flat_obs, codes=h.eye[batch["codes"].reshape(-1)], acts=flat_acts,
                             logp=batch["logp"].reshape(-1), adv=adv.reshape(-1), returns=returns.reshape(-1))
        pi = h.model.pi
        aux = {"bc": (lambda: bc_loss(pi, h.expert, h.eye, cfg.bc_batch_size, h.gen, discrete=h.discrete),
                      self.bc_weight()),
               # kept (weight 0, never called) without an anchor, so that every run logs the same scalars
               "anchor": ((anchor_loss(pi, self.anchor_pi, ppo_batch, cfg.bc_batch_size, h.gen), cfg.anchor_weight)
                          if self.anchor_pi is not None else (lambda: torch.zeros(()), 0.0))}
        losses = ppo_update(pi, self.value, self.optimizer, ppo_batch, cfg.ppo, h.gen, aux_losses=aux,
                            train_policy=h.iteration >= cfg.value_warmup)
        reward_stats = h.reward.scalars()
        check_finite({**losses, **stats}, h.iteration)
        elapsed = time.perf_counter() - t0
        out = {f"losses/{k}": v for k, v in losses.items()}
        out.update(reward_stats)
        out.update(stats)
        out.update({"rollout/disc_reward": float(disc_rew.mean()), "rollout/reward": float(rews.mean()),
                    "rollout/bonus": float(batch["bonus"].mean())})
        if cfg.imitation.bc_schedule != "fixed":
            out["losses/bc_weight"] = self.bc_weight()
        out.update(h.episode_scalars())
        out.update({"perf/sps": T * N / elapsed, "perf/rollout_sps": T * N / t_rollout,
                    "perf/global_step": float(h.global_step)})
        return out

    def bc_weight(self) -> float:
        """The BC term's weight this iteration: `--train.bc-weight`, or with the `anneal` schedule that decayed
        linearly to 0 over the run (the policy is held near the demonstrations first, then left to the reward)."""
        h = self.host
        if h.cfg.imitation.bc_schedule == "anneal":
            return h.cfg.bc_weight * max(0.0, 1.0 - h.iteration / max(self.total_iterations, 1))
        return h.cfg.bc_weight

    # ------------------------------------------------------------------------------------------ checkpoints
    def state_dict(self) -> dict[str, Any]:
        return {"value": self.value.state_dict(), "optimizer": self.optimizer.state_dict(),
                "anchor_pi": self.anchor_pi.state_dict() if self.anchor_pi is not None else None}

    def load_state_dict(self, state: dict[str, Any]) -> None:
        self.value.load_state_dict(state["value"])
        self.optimizer.load_state_dict(state["optimizer"])
        if self.anchor_pi is not None and state.get("anchor_pi") is not None:
            self.anchor_pi.load_state_dict(state["anchor_pi"])
