"""The ablation switches of Directed-Info GAIL: codes that carry nothing (`shuffle_codes`) and q trained with the
policy (`q_lr`)."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from digail.config import PPOConfig, TrainConfig
from digail.data.trajectory import Trajectory
from digail.errors import UserError


def _demos() -> list[Trajectory]:
    rng = np.random.default_rng(0)
    return [Trajectory(obs=rng.normal(size=(41, 3)).astype(np.float32),
                       acts=rng.uniform(-2, 2, size=(40, 1)).astype(np.float32)) for _ in range(3)]


def _trainer(**overrides):
    import gymnasium as gym

    from digail.algos.directed_info_gail import build_trainer
    from digail.nets.policy import ActionSpec
    from digail.nets.vae import HierarchicalPolicy

    torch.manual_seed(0)
    demos = _demos()
    vae = HierarchicalPolicy(3, 3, ActionSpec.from_space(gym.make("Pendulum-v1").action_space), (16,))
    vae.normalizer.fit(np.concatenate([d.obs for d in demos]))
    with torch.no_grad():  # a q that strongly prefers one code per half-space, so its codes are far from uniform
        vae.q.net[-1].bias.copy_(torch.tensor([4.0, 0.0, -4.0]))
    cfg = TrainConfig(hidden=(16,), backend="sync", value_warmup=0,
                      ppo=PPOConfig(num_envs=2, batch_size=128, minibatch_size=64, epochs=1), **overrides)
    return build_trainer("Pendulum-v1", demos, cfg, vae_model=vae, seed=0, run_dir=None, progress=False)


def _rollout_codes(trainer) -> np.ndarray:
    return trainer.learner.collect()["codes"].numpy().ravel()


def test_shuffled_codes_are_uniform_draws_in_the_rollouts_and_the_bc_term():
    plain, shuffled = _trainer(), _trainer(shuffle_codes=True)
    try:
        share = np.bincount(_rollout_codes(plain), minlength=3) / 128
        assert share[0] > 0.9  # q's codes: nearly always code 0
        share = np.bincount(_rollout_codes(shuffled), minlength=3) / 128
        assert share.min() > 0.2, share
        assert (plain.expert.codes == 0).float().mean() > 0.9
        assert np.bincount(shuffled.expert.codes.numpy(), minlength=3).min() > 20
    finally:
        plain.close()
        shuffled.close()


def test_q_trains_only_with_a_learning_rate_and_its_loss_falls():
    frozen, trained = _trainer(), _trainer(q_lr=1e-2, shuffle_codes=True)
    try:
        q0 = [p.detach().clone() for p in frozen.model.q.parameters()]
        assert "losses/q" not in frozen.iterate()
        assert all(torch.equal(a, b) for a, b in zip(q0, frozen.model.q.parameters(), strict=True))

        # q learns to predict the rollout's (here uniform) codes: its loss falls towards log 3 from far above
        batch = trained.learner.collect()
        first = trained.update_macro_policy(batch)["losses/q"]
        for _ in range(30):
            last = trained.update_macro_policy(batch)["losses/q"]
        assert first > 2.0 and last < first - 0.5, (first, last)
        state = trained.state_dict()
        assert "q_optimizer" in state
        trained.load_state_dict(state)
    finally:
        frozen.close()
        trained.close()


def test_q_training_needs_the_ppo_learner():
    with pytest.raises(UserError, match="q-lr"):
        TrainConfig(learner="sac", q_lr=1e-3)
    with pytest.raises(UserError, match="q-lr"):
        TrainConfig(q_lr=-1.0)
