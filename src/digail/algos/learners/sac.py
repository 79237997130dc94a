"""Soft actor-critic as the trainer's off-policy learner (`TrainConfig.learner` sac).

Per iteration, `steps_per_iteration` env steps with the current policy, each transition stored in the replay buffer
and handed to the reward, which learns from the replay buffer on its own schedule (a D-based reward: one step of D
on replayed agent pairs against the expert's every `--train.imitation.disc-every` env steps, with DAC's gradient
penalty and, with `SACConfig.absorbing`, absorbing states; Kostrikov et al. 2019), then the SAC update
(`digail.algos.sac.SACUpdate`) on sampled batches whose reward the current reward relabels.

Conventions (the update's own are in `digail.algos.sac`):

- r = the reward's (D's by default) + lambda_1 * the stored directed-info bonus log q(c' | s', c), as for PPO.
- c' for the bootstrap target is the code the macro-policy chose for s' during the rollout (stored with the
  transition): a sample of q (or argmax, `closed_loop_codes`), or the replayed expert code in expert-replay envs,
  chosen on the final observation where an episode ended. It is the code pi acted on at s', so the target follows
  the hierarchical policy that collected the data, and q runs once per env step, never per sampled batch.
- With absorbing states, V_abs = r(absorbing) / (1 - gamma) is the value of staying in the absorbing state forever
  (what the reward pays it, no entropy, no bonus); it is the target of a transition that ends by termination.
"""

from __future__ import annotations

import time
from typing import Any

import numpy as np
import torch

from digail.algos.aux_losses import bc_loss, qfiltered_bc_loss
from digail.algos.learners.base import Host
from digail.algos.optim import check_finite
from digail.algos.replay import ReplayBuffer
from digail.algos.rewards.base import EnvStep, Steps
from digail.algos.sac import SACBatch, SACUpdate
from digail.errors import UserError
from digail.utils import keep_heap_pages


class SACLearner:
    """The `sac` learner: its env loop, replay buffer, update schedule and the SAC update (its own critics).

    Args:
        host: the trainer whose envs, codes and reward it uses.
    """

    def __init__(self, host: Host) -> None:
        h = host
        self.host, self.cfg = h, h.cfg.sac
        if h.discrete:
            raise UserError("--train.learner sac needs continuous actions; use --train.learner ppo for this env.")
        if h.cfg.anchor_weight > 0:
            raise UserError("--train.anchor-weight is a PPO term; set it to 0 with --train.learner sac (the BC term, "
                            "--train.bc-weight, works with both).")
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
        self.updates = 0
        """SAC updates so far"""
        self._absorbing_steps = Steps(obs=torch.zeros(1, obs_dim, device=h.device),
                                      acts=torch.zeros(1, act_dim, device=h.device), batch={"rews": torch.zeros(1)},
                                      absorbing=True)
        """the absorbing state as steps the reward pays (with absorbing states)"""
        self._sac_stats: list[torch.Tensor] = []
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

    def _env_step(self) -> tuple[Steps, np.ndarray, np.ndarray]:
        """One step of every env with the current policy; the transitions go into the buffer. Returns them as the
        reward sees them (with their buffer positions), whether each ended its episode and whether each began one."""
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
        first = cstate.t_ep == 0
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
        stored = Steps(obs=torch.from_numpy(st.obs_n).to(h.device), acts=torch.from_numpy(executed).to(h.device),
                       batch={"codes": torch.from_numpy(st.codes)}, idx=torch.from_numpy(positions))
        prev[:] = next_codes
        st.obs_n, st.codes = next_n, next_codes
        h.global_step += n
        return stored, np.logical_or(terms, truncs), first

    # --------------------------------------------------------------------------------------------- updates
    def sample(self, n: int) -> Steps:
        """n transitions drawn from the buffer with the trainer's generator, as the reward sees them."""
        idx = self.buffer.sample_indices(n, self.host.gen)
        b = self.buffer.get(idx)
        return Steps(obs=b["obs"], acts=b["acts"], batch=b, idx=idx)

    def rewards(self, b: dict[str, torch.Tensor], idx: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        """The replayed transitions' reward from the current reward (plus the bonus), the imitation reward's part of
        it, and V_abs (0 without absorbing states); `idx` are their buffer positions."""
        h = self.host
        with torch.no_grad():
            rews, disc_rew = h.with_bonus(h.reward.rewards(Steps(obs=b["obs"], acts=b["acts"], batch=b, idx=idx)), b)
            v_abs = torch.zeros((), device=h.device)
            if self.cfg.absorbing:
                v_abs = h.reward.rewards(self._absorbing_steps).reshape(()) / (1.0 - self.cfg.gamma)
        return rews, disc_rew, v_abs

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
        """One step of every env, handed to the reward (which learns from the buffer on its own schedule once it
        holds `learning_starts` transitions), then the step's share of SAC updates (`utd` per env step)."""
        cfg, n = self.cfg, self.host.envs.num_envs
        t1 = time.perf_counter()
        stored, done, first = self._env_step()
        self._t_env += time.perf_counter() - t1
        learning = self.buffer.size >= max(cfg.learning_starts, 1)
        self.host.reward.update(EnvStep(stored, done, first, sample=self.sample if learning else None))
        if not learning:
            return
        self._update_debt += n * cfg.utd
        while self._update_debt >= 1.0:
            self._update_debt -= 1.0
            self._sac_stats.append(self.update_policy())

    def iterate(self) -> dict[str, float]:
        """One iteration: `steps_per_iteration` env steps, each followed by its share of reward and SAC updates."""
        h, cfg = self.host, self.cfg
        t0 = time.perf_counter()
        n = h.envs.num_envs
        self._normalize = h.model.normalizer.numpy_fn()
        self._sac_stats, self._t_env, self._bc_kept = [], 0.0, []
        if self.sac.bc is not None:
            self.sac.bc = (self.sac.bc[0], self.bc_weight())
        with h.frozen_codes():  # q is frozen: one snapshot serves the whole iteration
            if h.rollout_state is None:  # the episodes under way end here
                h.rollout_state = h.reset_envs()
            for _ in range(cfg.steps_per_env):
                self.step_and_update()
        sac_stats, t_env = self._sac_stats, self._t_env
        steps = cfg.steps_per_env * n
        names = (*SACUpdate.STAT_NAMES, "rollout/disc_reward", "sac/absorbing_value")
        out: dict[str, float] = {}
        if sac_stats:
            out.update(zip(names, torch.stack(sac_stats).mean(0).tolist(), strict=True))
        else:
            out.update({k: float("nan") for k in names})
        out.update(h.reward.scalars())
        # before the first updates the losses are placeholders (NaN), not failures
        if sac_stats:
            check_finite({k: out[k] for k in names}, h.iteration)
        elapsed = time.perf_counter() - t0
        recent = self.buffer.bonus[(self.buffer.pos - np.arange(1, min(steps, self.buffer.size) + 1))
                                   % self.buffer.capacity]
        out["rollout/bonus"] = float(recent.mean()) if len(recent) else float("nan")
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
                              "update_debt": self._update_debt, "updates": self.updates}}

    def load_state_dict(self, state: dict[str, Any]) -> None:
        own = state["offpolicy"]
        self.sac.load_state_dict(own["learner"])
        self.buffer.load_state_dict(own["buffer"])
        self._update_debt = float(own["update_debt"])
        self.updates = int(own["updates"])
