"""Fetch pick-and-place: the flat-observation env, its oracle phases and the scripted controller."""

from __future__ import annotations

import subprocess
import sys

import numpy as np
import pytest

import digail  # noqa: F401  (registers the envs)
from digail.envs.fetch import FETCH_ENV_ID, OBS_DIM, Phase, next_phase

pytestmark = pytest.mark.mujoco


def _make():
    pytest.importorskip("gymnasium_robotics")
    from digail.envs import make_env

    return make_env(FETCH_ENV_ID)


def _episode(env, seed: int) -> tuple[list[int], bool, list[np.ndarray]]:
    from digail.experts.fetch import fetch_expert

    obs, info = env.reset(seed=seed)
    labels, observations = [info["subtask"]], [obs]
    while True:
        obs, _, terminated, truncated, info = env.step(fetch_expert(env))
        labels.append(info["subtask"])
        observations.append(obs)
        if terminated or truncated:
            return labels, bool(info["is_success"]), observations


def test_import_digail_does_not_import_gymnasium_robotics() -> None:
    code = "import sys, digail; assert 'gymnasium_robotics' not in sys.modules, 'imported eagerly'"
    subprocess.run([sys.executable, "-c", code], check=True)


def test_flat_observation_is_observation_then_desired_goal() -> None:
    env = _make()
    obs, info = env.reset(seed=3)
    inner = env.unwrapped.fetch._get_obs()
    assert env.observation_space.shape == (OBS_DIM,) and obs.shape == (OBS_DIM,)
    np.testing.assert_allclose(obs[:25], inner["observation"])
    np.testing.assert_allclose(obs[25:28], inner["desired_goal"])
    np.testing.assert_allclose(obs[3:6], inner["achieved_goal"])  # the object position
    assert info["subtask"] == Phase.REACH
    _, _, _, _, info = env.step(env.action_space.sample())
    assert "subtask" in info and "is_success" in info
    env.close()


def test_scripted_expert_succeeds_and_phases_run_in_order() -> None:
    env = _make()
    successes = 0
    for seed in range(20):
        labels, success, _ = _episode(env, seed=1000 + seed)
        assert len(labels) == 51  # 50-step time limit, one label per observation
        steps = np.diff(labels)
        assert labels[0] == Phase.REACH and set(steps.tolist()) <= {0, 1}, f"seed {seed}: {labels}"
        if success:
            successes += 1
            assert labels[-1] == Phase.PLACE, f"seed {seed}: a success must end in place"
            assert sorted(set(labels)) == [0, 1, 2, 3]
    env.close()
    assert successes >= 18, f"scripted expert succeeded on {successes}/20 episodes"


def test_phase_tracker_is_monotone_and_advances_one_stage_at_a_time() -> None:
    obs = np.zeros(OBS_DIM)
    obs[0:3] = [1.3, 0.7, 0.435]  # gripper 1 cm right above the object
    obs[3:6] = [1.3, 0.7, 0.425]
    obs[9:11] = 0.022  # fingers closed on it
    obs[25:28] = obs[3:6]  # ... which already sits on the goal
    assert next_phase(Phase.REACH, obs) == Phase.GRASP  # only one stage, although all conditions hold
    assert next_phase(Phase.GRASP, obs) == Phase.CARRY
    assert next_phase(Phase.CARRY, obs) == Phase.PLACE
    far = obs.copy()
    far[3:6] = [1.1, 0.5, 0.425]
    assert next_phase(Phase.PLACE, far) == Phase.PLACE  # never back within an episode
    open_fingers = obs.copy()
    open_fingers[9:11] = 0.05
    assert next_phase(Phase.GRASP, open_fingers) == Phase.GRASP


def test_fetch_expert_refuses_other_envs() -> None:
    import gymnasium as gym

    from digail.experts.fetch import fetch_expert

    with pytest.raises(TypeError, match="FlatFetchPickAndPlace"):
        fetch_expert(gym.make("Pendulum-v1"))


# ------------------------------------------------------------------------------- task measures (eval.json)
def _summary(policy, episodes: int, seed: int = 10_000):
    from digail.envs.episodes import play_episodes
    from digail.eval.returns import summarize

    env = _make()
    eps = play_episodes(env, policy, episodes, seed, keep=True)
    env.close()
    return summarize(eps, FETCH_ENV_ID), eps


def test_scripted_expert_scores_success_and_grasp_rates_of_one() -> None:
    from digail.experts.fetch import fetch_expert

    result, eps = _summary(lambda env, obs: fetch_expert(env), 10)
    assert result["success_rate"] == 1.0 and result["grasp_rate"] == 1.0
    # mean_return is the paper's dense return (minus the object-goal distance per step), sparse beside it
    dense = [sum(-np.linalg.norm(o[3:6] - o[25:28]) for o in ep.obs[1:]) for ep in eps]
    assert result["mean_return"] == pytest.approx(np.mean(dense)) == pytest.approx(result["dense_return"])
    assert result["sparse_return"] == pytest.approx(np.mean([ep.ret for ep in eps]))
    assert -10 < result["mean_return"] < 0 and result["sparse_return"] <= -10


def test_do_nothing_policy_never_grasps_and_succeeds_only_where_the_goal_starts_at_the_object() -> None:
    result, eps = _summary(lambda env, obs: np.zeros(4, np.float32), 10)
    assert result["grasp_rate"] == 0.0 and result["lift_rate"] == 0.0
    start_distance = np.array([np.linalg.norm(ep.obs[0][3:6] - ep.obs[0][25:28]) for ep in eps])
    # gymnasium-robotics samples some goals within 5 cm of the object (3 of 100 from seed 10000); none of these
    assert result["success_rate"] == float(np.mean(start_distance < 0.05)) == 0.0
    # the object never moves, so the dense return is 50 times its start distance to the goal
    assert result["mean_return"] == pytest.approx(-50 * start_distance.mean(), rel=1e-3)


def test_fetch_smoke_pipeline_pretrain_digail_l2_evaluate(tmp_path) -> None:
    """demos -> VAE (K = 4) -> Directed-Info GAIL + L2 for two iterations -> evaluate with the task measures."""
    import json

    pytest.importorskip("gymnasium_robotics")
    from digail.cli import main

    demos, vae, run = tmp_path / "demos", tmp_path / "vae", tmp_path / "digail"
    assert main(["demos", FETCH_ENV_ID, "--episodes", "4", "--out", str(demos)]) == 0
    assert main(["pretrain", "--demos", str(demos), "--preset", "smoke", "--codes", "4", "--out", str(vae)]) == 0
    assert main(["train", "--demos", str(demos), "--vae", str(vae), "--preset", "smoke", "--train.bc-weight", "1",
                 "--out", str(run)]) == 0
    config = json.loads((run / "config.json").read_text())
    assert config["train"]["bc_weight"] == 1.0 and config["train"]["iterations"] == 2
    assert main(["evaluate", str(run), "--episodes", "3"]) == 0
    ev = json.loads((run / "eval.json").read_text())
    for key in ("mean_return", "sparse_return", "success_rate", "grasp_rate"):
        assert np.isfinite(ev[key]), key
    assert ev["mean_return"] == ev["dense_return"] and ev["episodes"] == 3
    assert ev["expert"]["success_rate"] == 1.0 and ev["expert"]["grasp_rate"] == 1.0


def test_relative_env_plays_the_same_episode_in_the_relative_view() -> None:
    """The scripted expert on the relative env and on the flat one, same seed: the same actions, labels and
    success, and each relative observation is `relative_view` of the flat one; the shipped demonstrations of the
    two are the same episodes."""
    import torch

    from digail.commands.train import load_demos
    from digail.envs import make_env
    from digail.envs.fetch import FETCH_RELATIVE_ENV_ID, RELATIVE_DIM, relative_view

    flat_env = _make()
    rel_env = make_env(FETCH_RELATIVE_ENV_ID)
    try:
        assert rel_env.observation_space.shape == (RELATIVE_DIM,)
        flat_labels, flat_ok, flat_obs = _episode(flat_env, 3)
        rel_labels, rel_ok, rel_obs = _episode(rel_env, 3)
    finally:
        flat_env.close()
        rel_env.close()
    assert rel_labels == flat_labels and rel_ok and flat_ok
    want = relative_view(torch.as_tensor(np.array(flat_obs))).numpy()
    np.testing.assert_allclose(np.array(rel_obs), want, atol=1e-12)
    flat_demos, _ = load_demos("digail/fetchpickandplace/expert-v0", episodes=2)
    rel_demos, env_id = load_demos("digail/fetchpickandplacerelative/expert-v0", episodes=2)
    assert env_id == FETCH_RELATIVE_ENV_ID
    for f, r in zip(flat_demos, rel_demos, strict=True):
        np.testing.assert_allclose(np.asarray(r.obs), relative_view(torch.as_tensor(np.asarray(f.obs))).numpy(),
                                   atol=1e-6)
        np.testing.assert_array_equal(np.asarray(r.acts), np.asarray(f.acts))
