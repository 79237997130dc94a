"""Directed-Info GAIL (Sharma et al., ICLR 2019, section 3 and eq. 4).

Extends GAIL with K sub-task codes: the macro-policy q(c_t | s_t, c_{t-1}) from VAE pre-training is frozen and
picks codes during rollouts (closed-loop on the agent's own states, or replaying q's segmentation of a random
expert demonstration), and the reward gains the directed-information bonus lambda_1 * log q(c_t | s_t, c_{t-1}).
"""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path
from typing import Any

import numpy as np
import torch
from torch import nn

from digail.algos.fast.inference import log_softmax
from digail.algos.gail import GAIL
from digail.algos.inference import code_net
from digail.algos.optim import adam
from digail.algos.rewards.base import LogitsReward
from digail.config import TrainConfig
from digail.data.trajectory import Trajectory
from digail.errors import UserError
from digail.nets.vae import HierarchicalPolicy
from digail.utils import seed_everything


class DirectedInfoGAIL(GAIL):
    """GAIL on pi(a | s, c) with codes from a frozen macro-policy q and the directed-info bonus.

    Sign of the bonus: paper eq. 4 minimises `-lambda_1 L_1` with `L_1 = sum_t E[log q(c_t | c_{<t}, tau_{1:t})]`
    (the variational lower bound of the directed information I(tau -> c)), i.e. the policy *maximises*
    lambda_1 * log q. As a reward, log q(c_t | s_t, c_{t-1}) scores the state s_t, so it is credited to the
    transition (s_{t-1}, a_{t-1}) that produced s_t. The authors' released code subtracted it; we do not.

    Code sources per env (docs/design.md): the first `round(replay_fraction * N)` envs replay q's causal segmentation
    of a random expert demonstration (samples of p(c^{1:t})), continued closed-loop past its end; the others
    sample c_t ~ q(. | s_t, c_{t-1}) on their own states.
    """

    method = "digail"

    def __init__(self, *args, **kwargs) -> None:  # type: ignore[no-untyped-def]
        super().__init__(*args, **kwargs)
        self.n_replay = int(round(self.cfg.replay_fraction * self.envs.num_envs))
        # q's segmentations with a column of -1 (past a demonstration's end) and a row of -1 (the replay index of
        # closed-loop envs): a code is replayed where the table holds one, with no further checks per step
        length = self.expert.replay_codes.shape[1]
        self._replay_table = np.full((len(self.expert.replay_codes) + 1, length + 1), -1, dtype=np.int64)
        self._replay_table[:-1, :length] = self.expert.replay_codes
        if self.cfg.shuffle_codes:  # the ablation: the BC term's expert codes are uniform draws, made once
            self.expert = replace(self.expert, codes=torch.randint(self.K, self.expert.codes.shape, generator=self.gen
                                                                   ).to(self.expert.codes.device))
        self.q_optimizer = None
        """Adam of q while it trains with the policy (`q_lr` > 0); None while q stays frozen"""
        if self.cfg.q_lr > 0:
            self.model.q.requires_grad_(True)
            self.q_optimizer = adam(list(self.model.q.parameters()), lr=self.cfg.q_lr)

    def start_episodes(self, idx: np.ndarray) -> None:
        super().start_episodes(idx)
        demo = self.np_rng.integers(len(self.expert.replay_codes), size=len(idx))
        self.codes_state.replay_idx[idx] = np.where(idx < self.n_replay, demo, -1)

    def _is_closed_loop(self, i: int) -> bool:
        return i >= self.n_replay

    def choose_codes(self, obs_n: np.ndarray, prev: np.ndarray, t_ep: np.ndarray,
                      env_idx: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """c_t and log q(c_t | s_t, c_{t-1}) for the envs `env_idx`; obs_n, prev and t_ep are aligned with it.

        The rollout hot path, so it runs in NumPy: q from its weight snapshot (the rollout's, else a fresh one),
        which takes prev as integers, and the Gumbel noise of sampled codes from `np_rng`.
        """
        snap = self._q_snap if self._q_snap is not None else code_net(self.model.q, self.model.obs_dim)
        logp_all = log_softmax(snap(obs_n, prev))
        if self.cfg.closed_loop_codes == "argmax":
            codes = logp_all.argmax(-1)
        else:
            codes = (logp_all + self.np_rng.gumbel(size=logp_all.shape)).argmax(-1)  # a sample of q (Gumbel-max)
        if self.cfg.shuffle_codes:
            codes = self.np_rng.integers(self.K, size=len(codes))
        elif self.n_replay:
            table = self._replay_table
            replayed = table[self.codes_state.replay_idx[env_idx], np.minimum(t_ep, table.shape[1] - 1)]
            codes = np.where(replayed >= 0, replayed, codes)
        logq = logp_all[np.arange(len(codes)), codes]
        return codes, logq

    def update_macro_policy(self, batch: dict[str, torch.Tensor]) -> dict[str, float]:
        """With `q_lr` > 0, one pass of Adam steps of q on -log q(c_t | s_t, c_{t-1}) over the rollout's steps (its
        first step is skipped: its c_{t-1} belongs to the rollout before); returns `losses/q`. A no-op otherwise."""
        if self.q_optimizer is None:
            return {}
        obs, codes = batch["obs"][1:], batch["codes"][1:]
        started = (batch["terminated"] | batch["truncated"])[:-1]  # an episode starts at t: c_{t-1} is the start
        prev = self.eye[batch["codes"][:-1]] * (~started).unsqueeze(-1)
        obs, codes, prev = obs.reshape(-1, obs.shape[-1]), codes.reshape(-1), prev.reshape(-1, self.K)
        size = self.cfg.ppo.minibatch_size
        perm = torch.randperm(len(obs), generator=self.gen)
        losses = []
        for start in range(0, len(obs), size):
            idx = perm[start:start + size]
            loss = nn.functional.cross_entropy(self.model.q(obs[idx], prev[idx]), codes[idx])
            self.q_optimizer.zero_grad(set_to_none=True)
            loss.backward()
            self.q_optimizer.step()
            losses.append(float(loss.detach()))
        return {"losses/q": float(np.mean(losses))}

    def state_dict(self) -> dict[str, Any]:
        state = super().state_dict()
        if self.q_optimizer is not None:
            state["q_optimizer"] = self.q_optimizer.state_dict()
        return state

    def load_state_dict(self, state: dict[str, Any]) -> None:
        super().load_state_dict(state)
        if self.q_optimizer is not None:
            self.q_optimizer.load_state_dict(state["q_optimizer"])


# -------------------------------------------------------------------------------------------- the trainer
def build_trainer(env_id: str, demos: list[Trajectory], cfg: TrainConfig, *, vae_model: HierarchicalPolicy | None,
                  seed: int, run_dir: Path | None, device: str | torch.device = "cpu",
                  progress: bool = True, reward_fn: LogitsReward | None = None) -> GAIL:
    """The trainer for `cfg.method` with its policy initialised as configured.

    digail needs the pre-trained VAE (its q and normaliser; its decoder initialises pi when `init_from_vae`).
    gail uses one code and a fresh policy; the normaliser is fitted on the demonstrations.
    """
    from digail.nets.policy import ActionSpec

    # a fresh policy (gail's, or digail's without init_from_vae) draws its initial weights here, before the trainer
    # seeds itself: seeded now, they follow `seed` instead of whatever drew from torch's generator before
    seed_everything(seed)
    if cfg.method == "digail":
        if vae_model is None:
            raise UserError("Directed-Info GAIL needs a pre-trained VAE; pass --vae RUN "
                            "(make one with `digail pretrain --demos D`).")
        model = vae_model
        if not cfg.init_from_vae:
            fresh = HierarchicalPolicy(model.obs_dim, model.codes, model.action, cfg.hidden,
                                       decoder_obs=model.decoder_obs)
            model.pi.load_state_dict(fresh.pi.state_dict())
            if cfg.zero_code_weights:
                model.pi.zero_code_weights()
        return DirectedInfoGAIL(env_id, demos, model, cfg, seed=seed, run_dir=run_dir, device=device,
                                progress=progress, reward_fn=reward_fn)
    obs_dim = int(np.asarray(demos[0].obs).reshape(len(demos[0].obs), -1).shape[1])
    from digail.envs import make_env

    probe = make_env(env_id)
    action = ActionSpec.from_space(probe.action_space)
    probe.close()
    model = HierarchicalPolicy(obs_dim, 1, action, cfg.hidden)
    if cfg.zero_code_weights:
        model.pi.zero_code_weights()
    model.normalizer.fit(np.concatenate([np.asarray(t.obs) for t in demos]))
    return GAIL(env_id, demos, model, cfg, seed=seed, run_dir=run_dir, device=device, progress=progress,
                reward_fn=reward_fn)


def train(env_id: str, demos: list[Trajectory], vae_model: HierarchicalPolicy | None = None,
          cfg: TrainConfig | None = None, *, seed: int = 0, run_dir: str | Path | None = None,
          device: str | torch.device = "cpu", progress: bool = True) -> HierarchicalPolicy:
    """Train a hierarchical policy on `env_id` from demonstrations: the library form of `digail train`.

    Args:
        env_id: the Gymnasium id to roll out in (the demonstrations' environment).
        demos: the expert demonstrations the discriminator compares against.
        vae_model: a pre-trained VAE (`digail.pretrain`): Directed-Info GAIL freezes its q and starts pi from its
            decoder. It is copied, not changed.
        cfg: trainer settings; None takes the env's preset (`digail.envs.registry.preset_for`), run as
            Directed-Info GAIL when `vae_model` is given and as plain GAIL (one code, fresh policy) otherwise.
        seed: seeds the initial weights, the envs and the batches; the same seed gives the same numbers on CPU.
        run_dir: when given, the trainer writes `metrics.csv`, TensorBoard events and checkpoints there.
        device: torch device of the updates.
        progress: show a progress bar.

    Returns:
        The trained policy (q, prior, pi and the observation normaliser) in eval mode.
    """
    import copy

    if cfg is None:
        from dataclasses import replace

        from digail.envs.registry import preset_for

        cfg = replace(preset_for(env_id).train, method="gail" if vae_model is None else "digail")
    model = copy.deepcopy(vae_model) if vae_model is not None else None
    trainer = build_trainer(env_id, list(demos), cfg, vae_model=model, seed=seed,
                            run_dir=None if run_dir is None else Path(run_dir), device=device, progress=progress)
    try:
        trainer.train()
    finally:
        trainer.close()
    return trainer.model.eval()
