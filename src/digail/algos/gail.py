"""GAIL (Ho and Ermon, 2016) with a code-conditioned policy pi(a | s, c): the trainer Directed-Info GAIL extends.

With one code and no bonus this is plain GAIL. The loop per iteration: roll out the vector env, update the
discriminator on agent vs expert pairs, relabel rewards from it, run PPO (optionally with a BC term).
"""

from __future__ import annotations

import copy
import math
import time
from collections import deque
from collections.abc import Callable
from pathlib import Path
from typing import TYPE_CHECKING, Any

import gymnasium as gym
import numpy as np
import torch
from torch import nn

from digail.algos.aux_losses import anchor_loss, bc_loss
from digail.algos.discriminator import discriminator_update
from digail.algos.expert_data import expert_data
from digail.algos.optim import adam
from digail.algos.ppo import PPOBatch, compute_gae, ppo_update
from digail.algos.rollout import CodeState, RolloutState, collect_rollout
from digail.checkpoint import load_training_state, rng_state, save_model, save_training_state, set_rng_state
from digail.config import TrainConfig, to_dict
from digail.data.trajectory import Trajectory
from digail.envs.actions import env_action_fn
from digail.envs.vector import make_vec_env
from digail.errors import TrainingError, UserError
from digail.nets.critic import Discriminator, ValueNet, generator_reward
from digail.nets.vae import HierarchicalPolicy
from digail.scalars import ScalarLogger
from digail.utils import progress_bar, seed_everything

if TYPE_CHECKING:
    from digail.algos.sac import OffPolicyLoop

RewardFn = Callable[[torch.Tensor, dict[str, torch.Tensor]], torch.Tensor]
"""(D's logits_expert_is_high (T, N), the rollout batch) -> the policy's reward (T, N) before the bonus"""

CHECKPOINT_VERSION = 2
"""2: the PPO optimiser holds two parameter groups (policy, value), for `PPOConfig.policy_lr`"""


class GAIL:
    """GAIL with PPO on a code-conditioned policy (paper section 2.1; the paper's GAIL baseline uses K = 1).

    Args:
        env_id: Gymnasium id of the environment.
        demos: expert demonstrations.
        model: hierarchical policy whose `normalizer` (fitted on the demonstrations) and `q` stay fixed and whose
            `pi` is trained; for plain GAIL it has one code.
        cfg: trainer settings.
        seed: seeds torch, NumPy and the environments.
        run_dir: where checkpoints and scalars go (None: nowhere, e.g. in tests).
        device: torch device of the networks.
        progress: show a progress bar while training.
        reward_fn: the policy's reward before the bonus from D's `logits_expert_is_high` (T, N) and the rollout
            batch (default: `generator_reward(logits, cfg.reward)`; e.g. `lambda logits, batch: batch["rews"]`
            trains on the env's own reward).
    """

    method = "gail"

    def __init__(self, env_id: str, demos: list[Trajectory], model: HierarchicalPolicy, cfg: TrainConfig, *,
                 seed: int = 0, run_dir: Path | None = None, device: str | torch.device = "cpu",
                 progress: bool = True, reward_fn: RewardFn | None = None) -> None:
        self.env_id, self.cfg, self.seed = env_id, cfg, seed
        self.reward_fn: RewardFn = reward_fn or (lambda logits, batch: generator_reward(logits, cfg.reward))
        """the policy's reward before the bonus, from D's logits (T, N) and the rollout batch"""
        self.run_dir = Path(run_dir) if run_dir is not None else None
        self.device = torch.device(device)
        self.progress = progress
        self.np_rng = seed_everything(seed)
        self.gen = torch.Generator().manual_seed(seed)

        self.model = model.to(self.device)
        self.model.q.requires_grad_(False)
        self.model.prior.requires_grad_(False)
        self.model.normalizer.requires_grad_(False)
        self.K = model.codes
        if not model.action.discrete:
            with torch.no_grad():
                model.pi.log_std.clamp_(min=cfg.min_init_log_std)
        self.eye = torch.eye(self.K, device=self.device)
        obs_dim = model.obs_dim

        # the rollouts ignore the per-step infos, so the parallel backends skip shipping them
        num_envs = cfg.sac.num_envs if cfg.learner == "sac" else cfg.ppo.num_envs
        self.envs = make_vec_env(env_id, num_envs, cfg.backend, workers=cfg.env_workers, infos=False)
        probe = self.envs.probe
        self.discrete = isinstance(probe.action_space, gym.spaces.Discrete)
        self.n_actions = int(getattr(probe.action_space, "n", 0))
        # what the envs execute for a sampled action, which is also what D sees (identity for discrete actions)
        self._to_env_actions: Callable[[Any], Any] = env_action_fn(probe) or (lambda acts: acts)
        act_in_dim = self.n_actions if self.discrete else int(np.prod(probe.action_space.shape or (1,)))

        self.value = ValueNet(obs_dim, self.K, cfg.hidden).to(self.device)
        if cfg.zero_code_weights:
            self.value.zero_code_weights()
        self.disc = Discriminator(obs_dim, act_in_dim, cfg.hidden).to(self.device)
        self.optimizer = adam([{"params": list(self.model.pi.parameters()), "lr": cfg.ppo.effective_policy_lr},
                               {"params": list(self.value.parameters())}], lr=cfg.ppo.lr, eps=1e-5)
        self._total_iterations = cfg.iterations  # what `anneal_lr` decays over; `train(iterations=...)` sets it
        self.disc_optimizer = adam(list(self.disc.parameters()), lr=cfg.disc_lr)

        self.expert = expert_data(self.model, demos, self.act_input, discrete=self.discrete, device=self.device)
        """the demonstrations as D's and the BC term's tensors, and q's codes of them"""
        # a frozen copy of the initial policy for the anchor term (saved in checkpoints: resuming keeps the anchor)
        self._anchor_pi = copy.deepcopy(self.model.pi).requires_grad_(False) if cfg.anchor_weight > 0 else None
        self.iteration = 0
        self.global_step = 0
        self.recent_returns: deque[float] = deque(maxlen=50)
        self.recent_lengths: deque[float] = deque(maxlen=50)
        self.recent_closed_returns: deque[float] = deque(maxlen=50)
        self.rollout_state: RolloutState | None = None  # where the next rollout continues (None: fresh episodes)
        self._q_snap: Any = None  # weight snapshot of q, set for the duration of a rollout
        self._logger: ScalarLogger | None = None
        self.model_config: dict[str, Any] = {"kind": self.method, "method": self.method, "env_id": env_id,
                                             "seed": seed, "train": to_dict(cfg)}
        """what `model.pt` records as its config (`digail train` sets the run's config.json content)"""
        self.offpolicy: OffPolicyLoop | None = None
        """the off-policy learner's loop, buffer and critics (`cfg.learner` sac; None: PPO)"""
        if cfg.learner == "sac":
            from digail.algos.sac import OffPolicyLoop

            self.offpolicy = OffPolicyLoop(self, demos)

    # ------------------------------------------------------------------------------------------ actions
    def act_input(self, acts: torch.Tensor) -> torch.Tensor:
        """Actions as the discriminator sees them: one-hot (discrete) or executed (continuous)."""
        if self.discrete:
            return nn.functional.one_hot(acts.long(), self.n_actions).float()
        return self._to_env_actions(acts)

    # ----------------------------------------------------------------------------------- macro-policy hooks
    def start_episodes(self, idx: np.ndarray) -> None:
        """Reset the code state of the envs in `idx` at an episode start."""
        self.codes_state.prev[idx] = -1
        self.codes_state.t_ep[idx] = 0

    def choose_codes(self, obs_n: np.ndarray, prev: np.ndarray, t_ep: np.ndarray,
                      env_idx: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Codes c_t for normalised observations s_t given integer c_{t-1}, and log q(c_t | s_t, c_{t-1}), in
        NumPy (the rollout's hot path). One code: always 0."""
        n = len(obs_n)
        return np.zeros(n, dtype=np.int64), np.zeros(n, dtype=np.float32)

    # ------------------------------------------------------------------------------------------ rollouts
    def _reset_envs(self) -> RolloutState:
        """Fresh episodes in every env, seeded from (seed, iteration), and their first codes."""
        base = self.seed * 100_003 + self.iteration * 1_009
        obs, _ = self.envs.reset([base + i for i in range(self.envs.num_envs)])
        n = self.envs.num_envs
        self.codes_state = CodeState.new(n)
        self.start_episodes(np.arange(n))
        with torch.no_grad():
            obs_n = self.model.normalizer(torch.from_numpy(np.asarray(obs, np.float32)).to(self.device)).cpu().numpy()
        codes, _ = self.choose_codes(obs_n, self.codes_state.prev, self.codes_state.t_ep, np.arange(n))
        self.codes_state.prev = codes.copy()
        return RolloutState(obs_n=obs_n, codes=codes, code_state=self.codes_state, ep_returns=np.zeros(n),
                            ep_lengths=np.zeros(n, dtype=np.int64))

    def _env_actions(self, a: np.ndarray) -> np.ndarray:
        """Sampled actions -> what the envs execute; non-finite continuous actions stop the run."""
        if self.discrete:
            return a
        if not np.isfinite(a).all():
            raise TrainingError(f"the policy produced non-finite actions at iteration {self.iteration + 1}; the last "
                                "good checkpoint is kept - lower the learning rate or check the demonstrations.")
        return self._to_env_actions(a)

    @torch.no_grad()
    def collect(self) -> dict[str, torch.Tensor]:
        """One rollout of `steps_per_env` steps in every env (`collect_rollout`) as tensors on the device."""
        from digail.algos.inference import actor_critic, code_net

        obs_dim = self.model.obs_dim
        ac = actor_critic(self.model.pi, self.value, obs_dim)
        self._q_snap = code_net(self.model.q, obs_dim) if self.K > 1 else None
        if self.rollout_state is None:
            self.rollout_state = self._reset_envs()
        T = self.cfg.ppo.steps_per_env
        batch = collect_rollout(self.envs, ac, self.rollout_state, T, self.np_rng,
                                normalize=self.model.normalizer.numpy_fn(),
                                choose_codes=self.choose_codes, start_episodes=self.start_episodes,
                                episode_done=self._episode_done, env_actions=self._env_actions)
        self._q_snap = None
        self.global_step += T * self.envs.num_envs
        return {k: torch.from_numpy(v).to(self.device) for k, v in batch.items()}

    def _episode_done(self, i: int) -> None:
        assert self.rollout_state is not None
        ret = float(self.rollout_state.ep_returns[i])
        self.recent_returns.append(ret)
        self.recent_lengths.append(float(self.rollout_state.ep_lengths[i]))
        if self._is_closed_loop(i):
            self.recent_closed_returns.append(ret)

    def _is_closed_loop(self, i: int) -> bool:
        return True

    # ------------------------------------------------------------------------------------- discriminator
    def update_discriminator(self, obs_n: torch.Tensor, act_in: torch.Tensor) -> dict[str, float]:
        """`discriminator_update` on this rollout's (normalised obs, D-action) pairs against the expert's."""
        return discriminator_update(self.disc, self.disc_optimizer, torch.cat([obs_n, act_in], -1), self.expert.disc_in,
                                    updates=self.cfg.disc_updates, minibatch_size=self.cfg.disc_minibatch_size,
                                    gen=self.gen, compile=self.cfg.ppo.compile)

    # ---------------------------------------------------------------------------------------- iteration
    def iterate(self) -> dict[str, float]:
        """One training iteration; returns its scalars."""
        if self.offpolicy is not None:
            return self.offpolicy.iterate()
        t0 = time.perf_counter()
        batch = self.collect()
        t_rollout = time.perf_counter() - t0
        T, N = batch["logp"].shape
        flat_obs = batch["obs"].reshape(T * N, -1)
        flat_acts = batch["acts"].reshape(T * N, *batch["acts"].shape[2:])
        act_in = self.act_input(flat_acts)
        stats = self.update_discriminator(flat_obs, act_in)
        with torch.no_grad():
            logits = self.disc(flat_obs, act_in).reshape(T, N)
            disc_rew = self.reward_fn(logits, batch)
            bonus = self.cfg.bonus_weight * batch["bonus"]
            if self.cfg.bonus_code_entropy and self.model.codes > 1:
                bonus = bonus + self.cfg.bonus_weight * math.log(self.model.codes)
            rews = disc_rew + bonus
        adv, returns = compute_gae(rews, batch["values"], batch["terminated"], batch["truncated"],
                                   batch["final_values"], batch["last_values"], self.cfg.ppo.gamma,
                                   self.cfg.ppo.gae_lambda)
        if self.cfg.ppo.anneal_lr:
            frac = max(0.0, 1.0 - self.iteration / max(self._total_iterations, 1))
            bases = (self.cfg.ppo.effective_policy_lr, self.cfg.ppo.lr)  # the optimiser's groups, in order
            for group, base in zip(self.optimizer.param_groups, bases, strict=True):
                group["lr"] = base * frac
        ppo_batch = PPOBatch(obs=flat_obs, codes=self.eye[batch["codes"].reshape(-1)], acts=flat_acts,
                             logp=batch["logp"].reshape(-1), adv=adv.reshape(-1), returns=returns.reshape(-1))
        pi, cfg = self.model.pi, self.cfg
        aux = {"bc": (lambda: bc_loss(pi, self.expert, self.eye, cfg.bc_batch_size, self.gen, discrete=self.discrete),
                      cfg.bc_weight),
               # kept (weight 0, never called) without an anchor, so that every run logs the same scalars
               "anchor": ((anchor_loss(pi, self._anchor_pi, ppo_batch, cfg.bc_batch_size, self.gen), cfg.anchor_weight)
                          if self._anchor_pi is not None else (lambda: torch.zeros(()), 0.0))}
        losses = ppo_update(pi, self.value, self.optimizer, ppo_batch, cfg.ppo, self.gen, aux_losses=aux,
                            train_policy=self.iteration >= cfg.value_warmup)
        if not all(math.isfinite(v) for v in (*losses.values(), *stats.values())):
            bad = [k for k, v in {**losses, **stats}.items() if not math.isfinite(v)]
            raise TrainingError(f"non-finite loss ({', '.join(bad)}) at iteration {self.iteration + 1}; the last "
                                "good checkpoint is kept - lower the learning rate or check the demonstrations.")
        self.iteration += 1
        elapsed = time.perf_counter() - t0
        out = {f"losses/{k}": v for k, v in losses.items()}
        out.update(stats)
        out.update({
            "rollout/disc_reward": float(disc_rew.mean()),
            "rollout/reward": float(rews.mean()),
            "rollout/bonus": float(batch["bonus"].mean()),
            "rollout/ep_return": float(np.mean(self.recent_returns)) if self.recent_returns else float("nan"),
            "rollout/ep_length": float(np.mean(self.recent_lengths)) if self.recent_lengths else float("nan"),
            "rollout/ep_return_closed_loop": (float(np.mean(self.recent_closed_returns))
                                              if self.recent_closed_returns else float("nan")),
            "perf/sps": T * N / elapsed,
            "perf/rollout_sps": T * N / t_rollout,
            "perf/global_step": float(self.global_step),
        })
        return out

    def train(self, iterations: int | None = None,
              evaluate: Callable[[HierarchicalPolicy], dict[str, float]] | None = None) -> dict[str, float]:
        """Run until `iterations` (default: the config's) are done, checkpointing along the way.

        `evaluate(model)`, when given, is called every `cfg.eval_every` iterations (and after the last one); its
        scalars are logged as `eval/*` at the current env step. It must not draw from the trainer's generators
        (a deterministic closed-loop evaluation on its own envs does not), so evaluating leaves training as is.
        """
        total = self.cfg.iterations if iterations is None else iterations
        self._total_iterations = total
        if self.run_dir is not None and self._logger is None:
            # a resumed run continues its metrics at the checkpoint: rows the stopped run logged later go
            self._logger = ScalarLogger(self.run_dir, resume_step=self.global_step)
        last: dict[str, float] = {}
        bar = progress_bar(total, self.progress, desc=self.method, unit="it", initial=self.iteration)
        start_step, t_start = self.global_step, time.perf_counter()
        every = self.cfg.eval_every
        try:
            if evaluate is not None and every > 0 and self.iteration == 0 and self._logger is not None:
                # the starting point of the learning curve (the VAE's policy for digail)
                self._logger.log(0, {"iteration": 0.0, **{f"eval/{k}": float(v)
                                                          for k, v in evaluate(self.model).items()}})
                self.model.train()
            while self.iteration < total:
                last = self.iterate()
                sps = (self.global_step - start_step) / max(time.perf_counter() - t_start, 1e-9)
                bar.set_postfix(steps=self.global_step, sps=f"{sps:.0f}", ret=f"{last['rollout/ep_return']:.2f}",
                                d_acc=f"{last['disc/accuracy']:.2f}", bonus=f"{last['rollout/bonus']:.2f}",
                                refresh=False)  # drawn by update(), on its schedule
                bar.update(1)
                if evaluate is not None and every > 0 and (self.iteration % every == 0 or self.iteration == total):
                    last.update({f"eval/{k}": float(v) for k, v in evaluate(self.model).items()})
                    self.model.train()
                if self._logger is not None:
                    self._logger.log(self.global_step, {"iteration": float(self.iteration), **last})
                if self.iteration % self.cfg.checkpoint_every == 0 or self.iteration == total:
                    if self.run_dir is not None:
                        self.save_checkpoint(self.run_dir / "checkpoint.pt")
                    # Episodes restart at every checkpoint, with or without a run folder: a run resumed from
                    # this checkpoint (which cannot hold the envs' internal state) then continues exactly as
                    # the uninterrupted one, bit for bit.
                    self.rollout_state = None
        finally:
            bar.close()
            if self._logger is not None:  # flushes TensorBoard's events; a later train() opens a new writer
                self._logger.close()
                self._logger = None
        return last

    # --------------------------------------------------------------------------------------- checkpoints
    def state_dict(self) -> dict[str, Any]:
        return {
            "version": CHECKPOINT_VERSION,
            "method": self.method,
            "iteration": self.iteration,
            "global_step": self.global_step,
            "model": self.model.state_dict(),
            "value": self.value.state_dict(),
            "disc": self.disc.state_dict(),
            "optimizer": self.optimizer.state_dict(),
            "disc_optimizer": self.disc_optimizer.state_dict(),
            "rng": rng_state(self.gen, self.np_rng),
            "recent_returns": torch.tensor(list(self.recent_returns), dtype=torch.float64),
            "recent_lengths": torch.tensor(list(self.recent_lengths), dtype=torch.float64),
            "recent_closed_returns": torch.tensor(list(self.recent_closed_returns), dtype=torch.float64),
            "anchor_pi": self._anchor_pi.state_dict() if self._anchor_pi is not None else None,
            **({"learner": "sac", "offpolicy": self.offpolicy.state_dict()} if self.offpolicy is not None else {}),
        }

    def load_state_dict(self, state: dict[str, Any]) -> None:
        if not isinstance(state, dict):
            raise TypeError("a training checkpoint is a dict")
        version = int(state.get("version", 0))
        if version != CHECKPOINT_VERSION:
            raise UserError(f"this training checkpoint has format version {version}, but this digail resumes "
                            f"version {CHECKPOINT_VERSION}; start the training again (its model.pt still "
                            "evaluates).")
        learner = state.get("learner", "ppo")  # PPO checkpoints carry no key, as before the off-policy learner
        if learner != self.cfg.learner:
            raise UserError(f"this training checkpoint was made with --train.learner {learner}, not "
                            f"{self.cfg.learner}; resume it with its own settings.")
        self.iteration = int(state["iteration"])
        self.global_step = int(state["global_step"])
        self.model.load_state_dict(state["model"])
        self.value.load_state_dict(state["value"])
        self.disc.load_state_dict(state["disc"])
        self.optimizer.load_state_dict(state["optimizer"])
        self.disc_optimizer.load_state_dict(state["disc_optimizer"])
        set_rng_state(state["rng"], self.gen, self.np_rng)
        empty = torch.zeros(0, dtype=torch.float64)  # checkpoints written before these were kept
        for name in ("recent_returns", "recent_lengths", "recent_closed_returns"):
            recent: deque[float] = getattr(self, name)
            recent.clear()
            recent.extend(state.get(name, empty).tolist())
        if self._anchor_pi is not None and state.get("anchor_pi") is not None:
            self._anchor_pi.load_state_dict(state["anchor_pi"])
        if self.offpolicy is not None:
            self.offpolicy.load_state_dict(state["offpolicy"])
        self.rollout_state = None  # envs restart with fresh episodes seeded from (seed, iteration)

    def save_checkpoint(self, path: Path) -> None:
        """Atomically write the full training state (weights_only-loadable) and, beside it, `model.pt`."""
        save_training_state(Path(path), self.state_dict())
        save_model(Path(path).parent / "model.pt", self.model, kind=self.method, config=self.model_config,
                   env_id=self.env_id)

    def close(self) -> None:
        """Stop the training envs (worker processes or envpool threads); the trainer cannot collect after it."""
        self.envs.close()

    def load_checkpoint(self, path: Path) -> None:
        """Restore the training state `save_checkpoint` wrote; a broken or foreign file is one `UserError`."""
        state = load_training_state(Path(path), self.device)
        try:
            self.load_state_dict(state)
        except UserError:
            raise
        except Exception:  # noqa: BLE001  (missing keys, wrong shapes, wrong types: all one answer)
            raise UserError(f"training checkpoint {path} is incomplete or belongs to another model; start the "
                            "training again (its model.pt still evaluates).") from None
