"""GAIL (Ho and Ermon, 2016) with a code-conditioned policy pi(a | s, c): the trainer Directed-Info GAIL extends.

With one code and no bonus this is plain GAIL. The trainer owns the demonstrations, the codes, the imitation reward
(`digail.algos.rewards`: D and its updates by default) and the bonus; its learner (`digail.algos.learners`: PPO,
the paper's, or SAC) steps the envs and trains pi, one `iterate` per iteration.
"""

from __future__ import annotations

import contextlib
import math
import time
from collections import deque
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import gymnasium as gym
import numpy as np
import torch
from torch import nn

from digail.algos import fast
from digail.algos.expert_data import expert_data
from digail.algos.learners import LEARNERS, Learner
from digail.algos.rewards import Reward, build_reward
from digail.algos.rewards.base import LogitsReward
from digail.algos.rollout import CodeState, RolloutState
from digail.checkpoint import load_training_state, rng_state, save_model, save_training_state, set_rng_state
from digail.config import TrainConfig, to_dict
from digail.data.trajectory import Trajectory
from digail.envs.actions import env_action_fn
from digail.envs.vector import make_vec_env
from digail.errors import TrainingError, UserError
from digail.nets.vae import HierarchicalPolicy
from digail.scalars import ScalarLogger
from digail.utils import progress_bar, seed_everything

CHECKPOINT_VERSION = 2
"""2: the PPO optimiser holds two parameter groups (policy, value), for `PPOConfig.policy_lr`"""


class GAIL:
    """GAIL on a code-conditioned policy (paper section 2.1; the paper's GAIL baseline uses K = 1), trained by the
    learner `cfg.learner` names (`digail.algos.learners.LEARNERS`).

    It is the `Host` of its learner (`digail.algos.learners.base`) and of its reward (`digail.algos.rewards.base`):
    the public methods below are what they use (the envs' resets and actions, the codes, the bonus), and `learner`
    and `reward` are the objects it drives.

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
        reward_fn: a D-based reward's pay from D's `logits_expert_is_high` (T, N) and the rollout batch (default:
            `generator_reward(logits, cfg.imitation.logits_to_reward)`; e.g. `lambda logits, batch: batch["rews"]`
            trains on the env's own reward, as `--train.imitation.reward env` does).
    """

    method = "gail"

    def __init__(self, env_id: str, demos: list[Trajectory], model: HierarchicalPolicy, cfg: TrainConfig, *,
                 seed: int = 0, run_dir: Path | None = None, device: str | torch.device = "cpu",
                 progress: bool = True, reward_fn: LogitsReward | None = None) -> None:
        self.env_id, self.cfg, self.seed = env_id, cfg, seed
        self.demos = demos
        self.reward_fn = reward_fn
        """a D-based reward's pay from D's logits (T, N) and the rollout batch (None: the configured one)"""
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

        entry = LEARNERS[cfg.learner]
        self.fast_path = fast.enabled()
        """whether this trainer runs the fast path (`digail.algos.fast`): read once, here, and kept for every
        iteration (`digail train` records it in the run's config.json)"""
        # the rollouts ignore the per-step infos, so the parallel backends skip shipping them
        self.envs = make_vec_env(env_id, entry.num_envs(cfg), cfg.backend, workers=cfg.env_workers, infos=False)
        probe = self.envs.probe
        self.discrete = isinstance(probe.action_space, gym.spaces.Discrete)
        self.n_actions = int(getattr(probe.action_space, "n", 0))
        # what the envs execute for a sampled action, which is also what D sees (identity for discrete actions)
        self.to_env_actions: Callable[[Any], Any] = env_action_fn(probe) or (lambda acts: acts)
        """sampled actions (NumPy or torch, differentiable) -> what the envs execute"""
        self.iteration = 0
        self.global_step = 0
        self.rollout_state: RolloutState | None = None  # where the next rollout continues (None: fresh episodes)
        self._q_snap: Any = None  # weight snapshot of q, set while the codes are frozen (`frozen_codes`)

        try:
            with fast.pinned(self.fast_path):
                # the learner's nets draw their initial weights before D's (the order of PPO runs before learners)
                self.learner: Learner = entry.build(self)
                """what trains pi: its nets, optimisers and buffers (`digail.algos.learners`)"""
        except BaseException:
            self.envs.close()
            raise
        self.absorbing = entry.absorbing(cfg)
        """whether the learner uses absorbing states (DAC): the reward then pays the absorbing state too"""
        self.expert = expert_data(self.model, demos, self.act_input, discrete=self.discrete, device=self.device)
        """the demonstrations as the rewards' and the BC term's tensors, and q's codes of them"""
        with fast.pinned(self.fast_path):
            # D (a D-based reward's) draws its initial weights here, after the learner's nets, as it always has
            self.reward: Reward = build_reward(self)
            """the imitation reward (`--train.imitation.reward`, `digail.algos.rewards`): D and its updates, an
            optimal-transport match against the demonstrations, or a weighted sum of terms"""
        self.recent_returns: deque[float] = deque(maxlen=50)
        self.recent_lengths: deque[float] = deque(maxlen=50)
        self.recent_closed_returns: deque[float] = deque(maxlen=50)
        self._logger: ScalarLogger | None = None
        self.model_config: dict[str, Any] = {"kind": self.method, "method": self.method, "env_id": env_id,
                                             "seed": seed, "train": to_dict(cfg)}
        """what `model.pt` records as its config (`digail train` sets the run's config.json content)"""

    # ------------------------------------------------------------------------------------------ actions
    def act_input(self, acts: torch.Tensor) -> torch.Tensor:
        """Actions as the rewards and the BC term see them: one-hot (discrete) or executed (continuous)."""
        if self.discrete:
            return nn.functional.one_hot(acts.long(), self.n_actions).float()
        return self.to_env_actions(acts)

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
    def reset_envs(self) -> RolloutState:
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

    def env_actions(self, a: np.ndarray) -> np.ndarray:
        """Sampled actions -> what the envs execute; non-finite continuous actions stop the run."""
        if self.discrete:
            return a
        if not np.isfinite(a).all():
            raise TrainingError(f"the policy produced non-finite actions at iteration {self.iteration + 1}; the last "
                                "good checkpoint is kept - lower the learning rate or check the demonstrations.")
        return self.to_env_actions(a)

    @contextlib.contextmanager
    def frozen_codes(self) -> Iterator[None]:
        """q's weights as one NumPy snapshot for the block (q is frozen, and building it per step would cost more
        than the step)."""
        from digail.algos.inference import code_net

        self._q_snap = code_net(self.model.q, self.model.obs_dim) if self.K > 1 else None
        try:
            yield
        finally:
            self._q_snap = None

    def episode_done(self, i: int) -> None:
        """Tally the finished episode of env i (before its tallies are reset)."""
        assert self.rollout_state is not None
        ret = float(self.rollout_state.ep_returns[i])
        self.recent_returns.append(ret)
        self.recent_lengths.append(float(self.rollout_state.ep_lengths[i]))
        if self._is_closed_loop(i):
            self.recent_closed_returns.append(ret)

    def _is_closed_loop(self, i: int) -> bool:
        return True

    def episode_scalars(self) -> dict[str, float]:
        """The mean env return and length of the last 50 episodes, and the return of the closed-loop ones."""
        def mean(values: deque[float]) -> float:
            return float(np.mean(values)) if values else float("nan")

        return {"rollout/ep_return": mean(self.recent_returns), "rollout/ep_length": mean(self.recent_lengths),
                "rollout/ep_return_closed_loop": mean(self.recent_closed_returns)}

    def update_macro_policy(self, batch: dict[str, torch.Tensor]) -> dict[str, float]:
        """Train q on a rollout's codes where the method does (Directed-Info GAIL with `q_lr` > 0); one code: no-op."""
        return {}

    # -------------------------------------------------------------------------------------------- reward
    def with_bonus(self, imitation: torch.Tensor, batch: dict[str, torch.Tensor]) -> tuple[torch.Tensor, torch.Tensor]:
        """(r, the imitation reward): r = the imitation reward + lambda_1 * log q(c_t | s_t, c_{t-1})
        (`batch["bonus"]`, the transition's bonus, + lambda_1 log K with `bonus_code_entropy`).

        The one place the bonus is added: every learner's reward goes through it."""
        disc_rew = imitation
        w = self.cfg.bonus_weight
        bonus = w * batch["bonus"]
        if self.cfg.bonus_code_entropy and self.K > 1:
            bonus = bonus + w * math.log(self.K)
        return disc_rew + bonus, disc_rew

    # ---------------------------------------------------------------------------------------- iteration
    def iterate(self) -> dict[str, float]:
        """One training iteration of the learner (on the fast path or not, as when the trainer was built); returns
        its scalars."""
        with fast.pinned(self.fast_path):
            out = self.learner.iterate()
        self.iteration += 1
        return out

    def train(self, iterations: int | None = None,
              evaluate: Callable[[HierarchicalPolicy], dict[str, float]] | None = None) -> dict[str, float]:
        """Run until `iterations` (default: the config's) are done, checkpointing along the way.

        `evaluate(model)`, when given, is called every `cfg.eval_every` iterations (and after the last one); its
        scalars are logged as `eval/*` at the current env step. It must not draw from the trainer's generators
        (a deterministic closed-loop evaluation on its own envs does not), so evaluating leaves training as is.
        """
        total = self.cfg.iterations if iterations is None else iterations
        self.learner.total_iterations = total
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
                                d_acc=f"{last.get('disc/accuracy', math.nan):.2f}",
                                bonus=f"{last['rollout/bonus']:.2f}",
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
            "learner": self.cfg.learner,
            "model": self.model.state_dict(),
            **self.reward.state_dict(),  # D's "disc" and "disc_optimizer", where checkpoints have kept them
            "rng": rng_state(self.gen, self.np_rng),
            "recent_returns": torch.tensor(list(self.recent_returns), dtype=torch.float64),
            "recent_lengths": torch.tensor(list(self.recent_lengths), dtype=torch.float64),
            "recent_closed_returns": torch.tensor(list(self.recent_closed_returns), dtype=torch.float64),
            # the learner's keys sit beside the trainer's (PPO's "value", "optimizer", "anchor_pi"; SAC's
            # "offpolicy"), where checkpoints have always kept them
            **self.learner.state_dict(),
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
        self.reward.load_state_dict(state)
        set_rng_state(state["rng"], self.gen, self.np_rng)
        empty = torch.zeros(0, dtype=torch.float64)  # checkpoints written before these were kept
        for name in ("recent_returns", "recent_lengths", "recent_closed_returns"):
            recent: deque[float] = getattr(self, name)
            recent.clear()
            recent.extend(state.get(name, empty).tolist())
        self.learner.load_state_dict(state)
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
