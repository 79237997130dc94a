"""What D sees of the observation (`--train.imitation.disc-obs`): Fetch's relative view."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from digail.algos.rewards.views import ObsView, obs_view
from digail.config import PPOConfig, TrainConfig
from digail.data.trajectory import Trajectory
from digail.envs.fetch import relative_view
from digail.errors import UserError
from digail.imitation_config import ImitationConfig
from digail.nets.normalizer import ObsNormalizer


def _fetch_obs(n: int, seed: int) -> np.ndarray:
    obs = np.random.default_rng(seed).normal(size=(n, 28)).astype(np.float32)
    obs[:, 6:9] = obs[:, 3:6] - obs[:, 0:3]  # object relative to the gripper, as the env observes it
    return obs


def test_the_relative_view_ignores_where_on_the_table_the_scene_lies():
    obs = _fetch_obs(64, 0)
    moved = obs.copy()
    shift = np.array([0.3, -0.2], np.float32)  # gripper, object and goal moved together, horizontally
    for sl in (slice(0, 2), slice(3, 5), slice(25, 27)):
        moved[:, sl] += shift
    a, b = relative_view(torch.from_numpy(obs)), relative_view(torch.from_numpy(moved))
    assert a.shape == (64, 24)
    torch.testing.assert_close(a, b)
    # but a goal moved away from the object is seen
    moved[:, 25] += 0.1
    assert not torch.allclose(a, relative_view(torch.from_numpy(moved)))


def test_the_routes_relative_view_sees_the_landmarks_from_the_point():
    from digail.envs.landmark_route import relative_view as route_view

    obs = torch.tensor([[0.5, -0.5, 1.2, 1.2, -1.2, 1.2, -1.2, -1.2, 1.2, -1.2, 0.0, 0.0, 1.0, 0.0]])
    moved = obs.clone()
    moved[:, 0:10] += torch.tensor([0.1, 0.2] * 5)  # the point and every landmark shifted together
    torch.testing.assert_close(route_view(obs), route_view(moved))
    torch.testing.assert_close(route_view(obs)[0, :4], torch.tensor([0.7, 1.7, -1.7, 1.7]))


def test_the_view_undoes_the_policys_normaliser_and_normalises_its_features_on_the_demonstrations():
    demo = _fetch_obs(500, 1) * 3 + 1
    norm = ObsNormalizer(28).fit(demo)
    view = ObsView(relative_view, norm, demo)
    feats = view(norm(torch.from_numpy(demo)))
    torch.testing.assert_close(feats.mean(0), torch.zeros(24), atol=1e-4, rtol=0)
    torch.testing.assert_close(feats.std(0, unbiased=False), torch.ones(24), atol=1e-3, rtol=0)


def test_an_env_without_a_relative_view_is_refused_in_one_sentence():
    assert obs_view("Pendulum-v1", "all", ObsNormalizer(3), np.zeros((2, 3))) is None
    with pytest.raises(UserError, match="no relative view.*--train.imitation.disc-obs all"):
        obs_view("Pendulum-v1", "relative", ObsNormalizer(3), np.zeros((2, 3)))


def _fetch_trainer(**imitation):
    """A tiny GAIL trainer on Fetch with D on the relative view: two 10-step made-up demonstrations."""
    from digail.algos.directed_info_gail import build_trainer

    rng = np.random.default_rng(0)
    demos = [Trajectory(obs=_fetch_obs(11, i), acts=rng.uniform(-1, 1, (10, 4)).astype(np.float32))
             for i in range(2)]
    cfg = TrainConfig(method="gail", hidden=(8,), backend="sync",
                      ppo=PPOConfig(num_envs=1, batch_size=16, minibatch_size=8, epochs=1),
                      imitation=ImitationConfig(disc_obs="relative", **imitation))
    return build_trainer("digail/FetchPickAndPlace-v4", demos, cfg, vae_model=None, seed=0, run_dir=None,
                         progress=False)


def test_a_fetch_trainer_builds_d_on_the_view_for_agent_and_expert_alike():
    trainer = _fetch_trainer()
    try:
        assert trainer.reward.disc.net[0].in_features == 24 + 4
        assert trainer.reward.inputs.expert.shape == (20, 28)
        out = trainer.iterate()
        assert np.isfinite(out["disc/loss"])
    finally:
        trainer.close()


def test_goal_relabelling_adds_copies_with_later_goals_to_ds_expert_inputs():
    """`--train.imitation.relabel-goals 3` on Fetch: D's expert rows are the 20 demonstration steps and 3 copies of
    each whose goal (and so the view's goal-to-object part) is where the object is later; the actions are kept."""
    plain, trainer = _fetch_trainer(), _fetch_trainer(relabel_goals=3)
    try:
        x = trainer.reward.inputs.expert
        assert x.shape == (80, 28)
        torch.testing.assert_close(x[:20], plain.reward.inputs.expert)
        copies = x[20:].reshape(2, 3, 10, 28).permute(1, 0, 2, 3).reshape(3, 20, 28)  # demo-major -> copy-major
        for c in copies:
            torch.testing.assert_close(c[:, 24:], x[:20, 24:])  # the actions
            assert not torch.allclose(c[:, :24], x[:20, :24])  # the goal moved, so the view did
        assert np.isfinite(trainer.iterate()["disc/loss"])
    finally:
        plain.close()
        trainer.close()


def test_a_view_of_the_users_own_is_named_as_module_function(tmp_path, monkeypatch):
    """`--train.imitation.disc-obs module:function` builds D on the user's function; a broken one is one sentence."""
    (tmp_path / "my_views.py").write_text(
        "import torch\n"
        "def gap(obs):\n    return obs[:, :1] - obs[:, 1:2]\n"
        "def flat(obs):\n    return obs.sum()\n"
        "def nan(obs):\n    return obs * float('nan')\n"
        "NOT_A_FUNCTION = 3\n")
    monkeypatch.syspath_prepend(str(tmp_path))
    demo = np.random.default_rng(0).normal(size=(50, 3)).astype(np.float32)
    norm = ObsNormalizer(3).fit(demo)
    view = obs_view("Pendulum-v1", "my_views:gap", norm, demo)
    assert view is not None and view.dim == 1
    torch.testing.assert_close(view(norm(torch.from_numpy(demo)))[:, 0].mean(), torch.tensor(0.0), atol=1e-4, rtol=0)
    for ref, phrase in (("my_views:flat", r"returned \(\) for \(50, 3\)"), ("my_views:nan", "NaN"),
                        ("my_views:missing", "has no 'missing'"), ("my_views:NOT_A_FUNCTION", "not a function"),
                        ("no_such_module_here:gap", "cannot import module")):
        with pytest.raises(UserError, match=phrase):
            obs_view("Pendulum-v1", ref, norm, demo)
    with pytest.raises(UserError, match="all, relative or module:function"):
        ImitationConfig(disc_obs="positions")
