"""The env registry states each env's facts (`digail.envs.registry.EnvSpec`), and they are true of the env: its
spaces, its oracle labels, its reward convention, how it draws a frame, its gait features."""

from __future__ import annotations

import inspect
import re
from pathlib import Path

import numpy as np
import pytest

from digail.envs.registry import ENV_SPECS, env_spaces, make_env

CHEAP = ["digail/FourRooms-v0", "digail/CircleWorld-v0", "digail/WaypointCourse-v0", "Pendulum-v1"]
MUJOCO = ["InvertedPendulum-v5", "Hopper-v5", "Walker2d-v5"]
PARAMS = [*CHEAP, *(pytest.param(e, marks=pytest.mark.mujoco) for e in MUJOCO)]


def _random_episode(env_id: str, steps: int = 300, seed: int = 0) -> tuple[list[float], list[dict], bool]:
    """Rewards and infos (the reset's first) of one random-action episode, and whether it ended by termination."""
    env = make_env(env_id)
    try:
        env.action_space.seed(seed)
        _, info = env.reset(seed=seed)
        rewards, infos, terminated = [], [info], False
        for _ in range(steps):
            _, r, terminated, truncated, info = env.step(env.action_space.sample())
            rewards.append(float(r))
            infos.append(info)
            if terminated or truncated:
                break
        return rewards, infos, bool(terminated)
    finally:
        env.close()


@pytest.mark.parametrize("env_id", PARAMS)
def test_spaces_are_the_envs_and_made_once(env_id: str, monkeypatch: pytest.MonkeyPatch) -> None:
    env = make_env(env_id)
    obs_space, act_space = env.observation_space, env.action_space
    env.close()
    assert ENV_SPECS[env_id].spaces() == (obs_space, act_space)
    import digail.envs.registry as registry

    monkeypatch.setattr(registry, "make_env", lambda *a, **k: pytest.fail("spaces made the env a second time"))
    assert env_spaces(env_id) == (obs_space, act_space)


@pytest.mark.parametrize("env_id", PARAMS)
def test_labels_are_the_oracle_labels_the_env_gives(env_id: str) -> None:
    """An env with labels puts one of them in `info["subtask"]` at the reset and every step; one without gives
    none (the waypoint courses name theirs by the course, so only their presence is checked)."""
    spec = ENV_SPECS[env_id]
    _, infos, _ = _random_episode(env_id)
    if spec.labels:
        assert all(0 <= info["subtask"] < len(spec.labels) for info in infos)
    elif env_id == "digail/WaypointCourse-v0":
        assert all("subtask" in info for info in infos)
    else:
        assert not any("subtask" in info for info in infos)


def test_every_label_of_the_labelled_envs_occurs() -> None:
    """Each named label is one the env really uses: the scripted experts' demonstrations show all of them."""
    from conftest import expert_trajectories

    for env_id in ("digail/FourRooms-v0", "digail/CircleWorld-v0", "digail/LandmarkRoute-v0"):
        seen = {int(s) for t in expert_trajectories(env_id, 30) for s in t.subtasks}
        assert seen == set(range(len(ENV_SPECS[env_id].labels))), env_id


@pytest.mark.parametrize("env_id", PARAMS)
def test_reward_convention_holds_on_random_episodes(env_id: str) -> None:
    spec = ENV_SPECS[env_id]
    rewards, _, terminated = _random_episode(env_id)
    if spec.reward == "cost":
        assert max(rewards) <= 0.0 and not terminated
    elif spec.reward == "task":
        assert max(rewards) <= 1.0 and min(rewards) < 0.0
    else:  # survival: the alive bonus outweighs the rest (a step's reward can dip below 0 on a bad motion or a
        # fall), and random actions fall before the time limit
        assert np.mean(rewards) > 0.5 and terminated


@pytest.mark.parametrize("env_id", CHEAP)
def test_render_says_how_a_frame_is_drawn(env_id: str) -> None:
    spec = ENV_SPECS[env_id]
    if spec.render == "none":
        env = make_env(env_id)
        assert "rgb_array" not in env.metadata.get("render_modes", [])
        env.close()
        return
    pytest.importorskip("pygame") if spec.render == "pygame" else None
    env = make_env(env_id, render_mode="rgb_array")
    env.reset(seed=0)
    frame = np.asarray(env.render())
    env.close()
    assert frame.ndim == 3 and frame.shape[2] == 3 and frame.dtype == np.uint8


def test_a_video_of_an_env_that_cannot_draw_is_one_sentence() -> None:
    from digail.errors import UserError
    from digail.viz.video import play_episodes

    with pytest.raises(UserError, match="cannot draw its frames"):
        play_episodes(None, "digail/WaypointCourse-v0", 1, 0, render=True)


def test_gait_features_come_from_the_registry() -> None:
    from digail.eval.gait import hip_features

    for spec in ENV_SPECS.values():
        if spec.gait_features is None:
            with pytest.raises(ValueError, match="no gait phase"):
                hip_features(spec.env_id)
        else:
            assert hip_features(spec.env_id) == spec.gait_features
    assert {s.env_id for s in ENV_SPECS.values() if s.gait_features} == {"Hopper-v5", "Walker2d-v5"}


@pytest.mark.mujoco
@pytest.mark.parametrize("env_id", ["Hopper-v5", "Walker2d-v5"])
def test_gait_features_are_the_hip_angle_and_its_velocity(env_id: str) -> None:
    """The observation entries named are qpos[3] (the thigh joint, the first observed qpos being qpos[1]) and
    qvel[3] (after the observed qpos entries)."""
    env = make_env(env_id)
    obs, _ = env.reset(seed=0)
    data = env.unwrapped.data
    angle, velocity = ENV_SPECS[env_id].gait_features or (0, 0)
    assert obs[angle] == pytest.approx(data.qpos[3]) and obs[velocity] == pytest.approx(data.qvel[3])
    env.close()


def test_no_module_outside_the_registry_branches_on_an_env_id() -> None:
    """Env facts live in their registry entry: no `env_id == "..."` or `env_id.startswith("...")` in the library
    outside `digail/envs` (where each env's own module lives)."""
    import digail

    root = Path(inspect.getfile(digail)).parent
    pattern = re.compile(r"env_id\s*==\s*[\"'A-Z]|env_id\.startswith\(|==\s*FOUR_ROOMS")
    found = [f"{p.relative_to(root)}:{i}" for p in root.rglob("*.py") if "envs" not in p.relative_to(root).parts
             for i, line in enumerate(p.read_text().splitlines(), 1) if pattern.search(line)]
    assert not found, found


@pytest.mark.parametrize("env_id", ["digail/FourRooms-v0", "digail/CircleWorld-v0"])
def test_reward_convention_holds_for_the_expert(env_id: str) -> None:
    """What random actions rarely reach: a `task` env pays its success reward at the terminating step, a `cost`
    env never pays a positive reward, the expert's episodes included."""
    from conftest import expert_trajectories

    for t in expert_trajectories(env_id, 5):
        assert t.rews is not None
        if ENV_SPECS[env_id].reward == "task":
            assert t.terminated and t.rews[-1] > 0.0 and (t.rews[:-1] < 0.0).all()
        else:
            assert not t.terminated and (t.rews <= 0.0).all()
