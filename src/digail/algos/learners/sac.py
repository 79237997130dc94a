"""Soft actor-critic as the trainer's off-policy learner (`TrainConfig.learner` sac).

Per iteration, `steps_per_iteration` env steps with the current policy, each transition stored in the replay buffer
and followed by its share of updates: the trainer's D on replayed agent pairs against the expert's (with DAC's
gradient penalty and, with `SACConfig.absorbing`, absorbing states; Kostrikov et al. 2019), and the SAC update
(`digail.algos.sac.SACUpdate`) on sampled batches whose reward the trainer relabels with the current D.

Conventions (the update's own are in `digail.algos.sac`):

- r = the trainer's reward (D's reward + lambda_1 * the stored directed-info bonus log q(c' | s', c)), as for PPO.
- c' for the bootstrap target is the code the macro-policy chose for s' during the rollout (stored with the
  transition): a sample of q (or argmax, `closed_loop_codes`), or the replayed expert code in expert-replay envs,
  chosen on the final observation where an episode ended. It is the code pi acted on at s', so the target follows
  the hierarchical policy that collected the data, and q runs once per env step, never per sampled batch.
- With absorbing states, V_abs = r(absorbing) / (1 - gamma) is the value of staying in the absorbing state forever
  (its reward from D, no entropy, no bonus); it is the target of a transition that ends by termination.
"""

from __future__ import annotations

import time
from typing import Any

import numpy as np
import torch

from digail.algos.aux_losses import bc_loss, qfiltered_bc_loss
from digail.algos.learners.base import Host, check_finite
from digail.algos.replay import ReplayBuffer
from digail.algos.sac import SACBatch, SACUpdate
from digail.errors import UserError
from digail.utils import keep_heap_pages


class SACLearner:
    """The `sac` learner: its env loop, replay buffer, update schedule and the SAC update (its own critics).

    Args:
        host: the trainer whose envs, codes, D and reward it uses.
    """

    def __init__(self, host: Host) -> None:
        h = host
        self.host, self.cfg = h, h.cfg.sac
        if h.discrete:
            raise UserError("--train.learner sac needs continuous actions; use --train.learner ppo for this env.")
        if h.cfg.anchor_weight > 0:
            raise UserError("--train.anchor-weight is a PPO term; set it to 0 with --train.learner sac (the BC term, "
                            "--bc-weight, works with both).")
        obs_dim, act_dim = h.model.obs_dim, h.model.action.dim
        self.obs_dim, self.act_dim = obs_dim, act_dim
        pi = h.model.pi
        bc = None
        self._bc_kept: list[torch.Tensor] = []
        """the Q-filter's share of expert steps kept, per update of the iteration"""
        if h.cfg.bc_weight > 0:
            bc = (lambda: bc_loss(pi, h.expert, h.eye, h.cfg.bc_batch_size, h.gen, discrete=False), h.cfg.bc_weight)
            if h.cfg.imitation.bc_schedule == "qfilter":
                bc = (self._qfiltered_bc, h.cfg.bc_weight)
        space: Any = h.envs.probe.action_space
        clip = getattr(h.envs.probe.unwrapped, "canonical_action", None) is None  # `env_action_fn`'s rule
        bounds = (space.low, space.high) if clip else None
        self.sac = SACUpdate(pi, obs_dim, h.K, self.cfg, h.to_env_actions, h.device, bc=bc, bounds=bounds,
                             zero_code_weights=h.cfg.zero_code_weights)
        """the update: critics, targets, temperature and their optimisers"""
        self.buffer = ReplayBuffer(self.cfg.buffer_size, obs_dim, act_dim, h.K, h.device)
        if h.device.type == "cpu":
            keep_heap_pages()  # each update's temporaries would otherwise be page-faulted in anew
        self.total_iterations = h.cfg.iterations
        """the run's length (no schedule of SAC's reads it)"""
        self._update_debt = 0.0
        self._disc_debt = 0
        self.updates = 0
        """SAC updates so far"""
        self._v_abs: torch.Tensor | None = None
        """V_abs for the current D (None: to be computed); D's step and a checkpoint's load reset it"""
        self._sac_stats: list[torch.Tensor] = []
        self._disc_stats: list[torch.Tensor] = []
        self._t_env = 0.0
        self._normalize = h.model.normalizer.numpy_fn()
        """raw -> normalised observations in NumPy (refreshed per iteration: a checkpoint load replaces them)"""

    def _qfiltered_bc(self) -> torch.Tensor:
        h = self.host
        loss, kept = qfiltered_bc_loss(h.model.pi, h.expert, h.eye, h.cfg.bc_batch_size, h.gen, self.sac.critic,
                                       h.to_env_actions)
        self._bc_kept.append(kept)
        return loss

    def bc_weight(self) -> float:
        """The BC term's weight now: `--train.bc-weight`, or with the `anneal` schedule that decayed linearly to 0
        over the run."""
        h = self.host
        if h.cfg.imitation.bc_schedule == "anneal":
            return h.cfg.bc_weight * max(0.0, 1.0 - h.iteration / max(self.total_iterations, 1))
        return h.cfg.bc_weight

    # ---------------------------------------------------------------------------------------------- acting
    def _mean_actions(self, obs_n: np.ndarray, codes: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        pi, h = self.host.model.pi, self.host
        with torch.no_grad():
            obs = torch.from_numpy(obs_n).to(h.device)
            mean = pi.net(pi.inputs(obs, h.eye[torch.from_numpy(codes).to(h.device)]))
            return mean.cpu().numpy(), pi.log_std.clamp(-5.0, 2.0).exp().cpu().numpy()

    def _env_step(self) -> None:
        """One step of every env with the current policy; the transitions go into the buffer."""
        h = self.host
        assert h.rollout_state is not None
        st = h.rollout_state
        cstate, n = st.code_state, h.envs.num_envs
        all_idx = np.arange(n)
        normalize = self._normalize
        mean, std = self._mean_actions(st.obs_n, st.codes)
        acts = mean + std * h.np_rng.standard_normal(mean.shape, dtype=np.float32)
        executed = np.asarray(h.env_actions(acts), dtype=np.float32)
        next_obs, rews, terms, truncs, _, final = h.envs.step(executed)
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
            next_codes, bonus = h.choose_codes(stored_next, prev, cstate.t_ep, all_idx)
            stored_codes = next_codes.copy()
            for i in done:
                h.episode_done(int(i))
                st.ep_returns[i] = 0.0
                st.ep_lengths[i] = 0
            h.start_episodes(done)
            next_codes[done], _ = h.choose_codes(next_n[done], prev[done], cstate.t_ep[done], done)
        else:
            next_codes, bonus = h.choose_codes(next_n, prev, cstate.t_ep, all_idx)
            stored_next, stored_codes = next_n, next_codes
        positions = (self.buffer.pos + all_idx) % self.buffer.capacity
        self.buffer.add(obs=st.obs_n, codes=st.codes, acts=executed, next_obs=stored_next, next_codes=stored_codes,
                        terminated=terms, bonus=bonus, rews=rews)
        if h.disc is None:  # an episode-matching reward scores each episode as it ends
            h.rewarder.observe(positions, torch.from_numpy(st.obs_n).to(h.device), torch.from_numpy(st.codes),
                               np.logical_or(terms, truncs))
        prev[:] = next_codes
        st.obs_n, st.codes = next_n, next_codes
        h.global_step += n

    # --------------------------------------------------------------------------------------------- updates
    def update_discriminator(self) -> torch.Tensor:
        """One step of the trainer's D on half a minibatch of replayed agent pairs (label 0; with absorbing states,
        the absorbing state once for each of them that terminated) and as many expert pairs (label 1), plus the
        gradient penalty. Returns the detached [loss, agent accuracy, expert accuracy, penalty]."""
        h = self.host
        half = max(1, h.cfg.disc_minibatch_size // 2)
        b = self.buffer.get(self.buffer.sample_indices(half, h.gen))
        x_agent = h.disc_input(b["obs"], b["acts"])
        if h.absorbing:
            x_agent = torch.cat([x_agent, h.absorbing_row().expand(int(b["terminated"].sum()), -1)])
        expert_in = h.expert_disc_in
        x_expert = expert_in[torch.randint(len(expert_in), (half,), generator=h.gen, device="cpu")]
        mix = x_expert[:0]
        if self.cfg.grad_penalty > 0:
            eps = torch.rand(half, 1, generator=h.gen).to(h.device)
            mix = eps * x_expert + (1 - eps) * x_agent[:half]
        self._v_abs = None
        return h.discriminator_step(x_agent, x_expert, mix, float(self.cfg.grad_penalty))

    def rewards(self, b: dict[str, torch.Tensor], idx: torch.Tensor | None = None
                ) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        """The sampled transitions' reward relabelled with the current D (plus the bonus; a reward without D reads
        its own score of the buffer positions `idx`, which it then needs), the imitation reward's part of it, and
        V_abs."""
        h = self.host
        if idx is None:
            if h.disc is None:
                raise ValueError("a reward without D reads its scores by buffer position: pass the batch's idx")
            idx = torch.zeros(len(b["obs"]), dtype=torch.long)
        with torch.no_grad():
            rews, disc_rew = h.replay_reward(b, idx)
            if self._v_abs is None:
                self._v_abs = torch.zeros((), device=h.device)
                if h.absorbing:
                    r_abs = h.disc_reward(h.disc_logits(h.absorbing_row()), {"rews": torch.zeros(1)})
                    self._v_abs = r_abs.reshape(()) / (1.0 - self.cfg.gamma)
        return rews, disc_rew, self._v_abs

    def update_policy(self) -> torch.Tensor:
        """One SAC update on a sampled batch; its stats and the batch's mean D reward."""
        h, B = self.host, self.cfg.batch_size
        idx = self.buffer.sample_indices(B, h.gen)
        b = self.buffer.get(idx)
        rews, disc_rew, v_abs = self.rewards(b, idx)
        batch = SACBatch(obs=b["obs"], code_1h=b["code_1h"], acts=b["acts"], next_obs=b["next_obs"],
                         next_code_1h=b["next_code_1h"], terminated=b["terminated"], rews=rews,
                         absorbing_value=v_abs)
        noise = torch.randn(2, B, self.act_dim, generator=h.gen).to(h.device)
        stats = self.sac.update(batch, noise[0], noise[1], train_policy=self.updates >= self.cfg.policy_warmup)
        self.updates += 1
        return torch.cat([stats, disc_rew.mean()[None], v_abs[None]])

    # ------------------------------------------------------------------------------------------- iteration
    def step_and_update(self) -> None:
        """One step of every env, then its share of D updates (one per `disc_every` env steps) and SAC updates
        (`utd` per env step), once the buffer holds `learning_starts` transitions."""
        cfg, n = self.cfg, self.host.envs.num_envs
        t1 = time.perf_counter()
        self._env_step()
        self._t_env += time.perf_counter() - t1
        if self.buffer.size < max(cfg.learning_starts, 1):
            return
        if cfg.disc_every > 0 and self.host.disc is not None:
            self._disc_debt += n
            while self._disc_debt >= cfg.disc_every:
                self._disc_debt -= cfg.disc_every
                self._disc_stats.append(self.update_discriminator())
        self._update_debt += n * cfg.utd
        while self._update_debt >= 1.0:
            self._update_debt -= 1.0
            self._sac_stats.append(self.update_policy())

    def iterate(self) -> dict[str, float]:
        """One iteration: `steps_per_iteration` env steps, each followed by its share of D and SAC updates."""
        h, cfg = self.host, self.cfg
        t0 = time.perf_counter()
        n = h.envs.num_envs
        self._normalize = h.model.normalizer.numpy_fn()
        self._sac_stats, self._disc_stats, self._t_env, self._bc_kept = [], [], 0.0, []
        if self.sac.bc is not None:
            self.sac.bc = (self.sac.bc[0], self.bc_weight())
        with h.frozen_codes():  # q is frozen: one snapshot serves the whole iteration
            if h.rollout_state is None:
                h.rewarder.flush()  # the episodes under way end here
                h.rollout_state = h.reset_envs()
            for _ in range(cfg.steps_per_env):
                self.step_and_update()
        sac_stats, disc_stats, t_env = self._sac_stats, self._disc_stats, self._t_env
        steps = cfg.steps_per_env * n
        names = (*SACUpdate.STAT_NAMES, "rollout/disc_reward", "sac/absorbing_value")
        out: dict[str, float] = {}
        if sac_stats:
            out.update(zip(names, torch.stack(sac_stats).mean(0).tolist(), strict=True))
        else:
            out.update({k: float("nan") for k in names})
        if disc_stats:
            loss, acc_a, acc_e, gp = torch.stack(disc_stats).mean(0).tolist()
        else:
            loss = acc_a = acc_e = gp = float("nan")
        out.update({"disc/loss": loss, "disc/acc_agent": acc_a, "disc/acc_expert": acc_e,
                    "disc/accuracy": 0.5 * (acc_a + acc_e), "disc/grad_penalty": gp})
        # before the first updates the losses are placeholders (NaN), not failures
        check_finite({k: v for k, v in out.items() if (disc_stats if k.startswith("disc/") else sac_stats)},
                     h.iteration)
        elapsed = time.perf_counter() - t0
        recent = self.buffer.bonus[(self.buffer.pos - np.arange(1, min(steps, self.buffer.size) + 1))
                                   % self.buffer.capacity]
        out["rollout/bonus"] = float(recent.mean()) if len(recent) else float("nan")
        out.update(h.rewarder.scalars())
        if h.cfg.imitation.bc_schedule != "fixed":
            out["losses/bc_weight"] = self.bc_weight()
        if self._bc_kept:
            out["losses/bc_kept"] = float(torch.stack(self._bc_kept).mean())
        out.update(h.episode_scalars())
        out.update({"perf/sps": steps / elapsed, "perf/rollout_sps": steps / max(t_env, 1e-9),
                    "perf/global_step": float(h.global_step), "sac/updates": float(len(sac_stats))})
        return out

    # ------------------------------------------------------------------------------------------ checkpoints
    def state_dict(self) -> dict[str, Any]:
        return {"offpolicy": {"learner": self.sac.state_dict(), "buffer": self.buffer.state_dict(),
                              "update_debt": self._update_debt, "disc_debt": self._disc_debt,
                              "updates": self.updates}}

    def load_state_dict(self, state: dict[str, Any]) -> None:
        own = state["offpolicy"]
        self.sac.load_state_dict(own["learner"])
        self.buffer.load_state_dict(own["buffer"])
        self._v_abs = None
        self._update_debt = float(own["update_debt"])
        self._disc_debt = int(own["disc_debt"])
        self.updates = int(own["updates"])
