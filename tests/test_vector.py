"""The training backends (digail.envs.vector) against the synchronous vector env on short episodes, a trainer on
each, a resume on each, and the shipped experts on envpool."""

from __future__ import annotations

import os
import signal
import time

import numpy as np
import pytest
import torch

from digail.config import TrainConfig
from digail.envs.vector import EnvpoolVecEnv, SubprocVecEnv, VecEnv, envpool_available, make_vec_env, resolve_backend
from digail.errors import UserError

needs_envpool = pytest.mark.skipif(not envpool_available(), reason="envpool is not installed")
SEEDS = [11, 12, 13, 14, 15]


def _actions(space, steps: int, n: int) -> list[np.ndarray]:
    space.seed(0)
    out = [np.stack([space.sample() for _ in range(n)]) for _ in range(steps)]
    return [a.astype(np.float32) if a.dtype.kind == "f" else a for a in out]


def _run(venv, actions: list[np.ndarray]) -> tuple[np.ndarray, list[tuple]]:
    obs, _ = venv.reset(SEEDS[: venv.num_envs])
    return obs, [venv.step(a) for a in actions]


def _assert_same(a, b, *, atol: float = 0.0, rtol: float = 0.0) -> int:
    """Step results `a` and `b` agree (exactly by default); returns how many episodes ended."""
    ended = 0
    for t, (ra, rb) in enumerate(zip(a, b, strict=True)):
        np.testing.assert_allclose(ra[0], rb[0], atol=atol, rtol=rtol, err_msg=f"obs at step {t}")
        np.testing.assert_allclose(ra[1], rb[1], atol=atol, rtol=max(rtol, 1e-6 if atol else 0.0),
                                   err_msg=f"rewards at step {t}")
        np.testing.assert_array_equal(ra[2], rb[2], err_msg=f"terminated at step {t}")
        np.testing.assert_array_equal(ra[3], rb[3], err_msg=f"truncated at step {t}")
        assert ra[5].keys() == rb[5].keys(), t
        for i in ra[5]:
            np.testing.assert_allclose(ra[5][i][0], rb[5][i][0], atol=atol, rtol=rtol, err_msg=f"final obs {t}")
        ended += len(ra[5])
    return ended


@pytest.mark.parametrize("env_id, kwargs, steps", [
    ("digail/FourRooms-v0", {"max_episode_steps": 10}, 40),  # discrete actions
    ("digail/CircleWorld-v0", {"max_episode_steps": 15}, 40),  # time limits
    pytest.param("Hopper-v5", {"max_episode_steps": 25}, 60, marks=pytest.mark.mujoco),  # both
])
def test_subproc_matches_sync_exactly(env_id, kwargs, steps):
    sync = VecEnv.of(env_id, 5, **kwargs)
    sub = SubprocVecEnv(env_id, 5, workers=2, **kwargs)
    try:
        acts = _actions(sync.single_action_space, steps, 5)
        obs_a, a = _run(sync, acts)
        obs_b, b = _run(sub, acts)
        np.testing.assert_array_equal(obs_a, obs_b)
        assert _assert_same(a, b) > 0
        assert any(r[3].any() for r in a)  # a truncation was compared
        for ra, rb in zip(a, b, strict=True):  # infos travel too (final infos always)
            assert [set(i) for i in ra[4]] == [set(i) for i in rb[4]]
            assert all(ra[5][i][1].keys() == rb[5][i][1].keys() for i in ra[5])
        # seeded resets restart every env's RNG: a second pass gives the same numbers
        _, c = _run(sub, acts)
        _assert_same(b, c)
    finally:
        sync.close()
        sub.close()


@pytest.mark.parametrize("env_id, kwargs, steps", [
    ("digail/CircleWorld-v0", {}, 260),  # full episodes: the circle scores in the final infos
    ("digail/CircleWorld-v0", {"max_episode_steps": 15}, 40),
    ("digail/FourRooms-v0", {}, 300),  # apples reached (terminations) and time limits
    ("digail/FourRooms-v0", {"max_episode_steps": 10}, 40),
])
def test_batched_synthetic_worlds_match_sync_exactly(env_id, kwargs, steps):
    """The array implementations give the wrapped envs' numbers bit for bit: observations, rewards,
    terminations, time limits, final observations, every info."""
    from digail.envs.registry import env_spec

    sync = VecEnv.of(env_id, 5, **kwargs)
    batched = make_vec_env(env_id, 5, "sync")
    spec = env_spec(env_id)
    assert spec is not None and spec.batched is type(batched)
    batched.close()
    batched = type(batched)(env_id, 5, **kwargs)
    try:
        acts = _actions(sync.single_action_space, steps, 5)
        if env_id == "digail/CircleWorld-v0":
            acts[3][2] = 0.0  # does not move
        obs_a, a = _run(sync, acts)
        obs_b, b = _run(batched, acts)
        np.testing.assert_array_equal(obs_a, obs_b)
        assert _assert_same(a, b) >= 10
        for ra, rb in zip(a, b, strict=True):
            assert ra[4] == rb[4]
            assert {i: f[1] for i, f in ra[5].items()} == {i: f[1] for i, f in rb[5].items()}
        bad = np.full((5, 2), np.nan, np.float32) if env_id == "digail/CircleWorld-v0" else np.full(5, 4)
        with pytest.raises(ValueError, match="finite|integers"):
            batched.step(bad)
    finally:
        sync.close()
        batched.close()


@pytest.mark.mujoco
@needs_envpool
@pytest.mark.parametrize("env_id, limit", [("Hopper-v5", 20), ("Walker2d-v5", 20), ("InvertedPendulum-v5", 4)])
def test_envpool_follows_gymnasium_dynamics(env_id, limit):
    """Reset noise off (envpool's reset RNG is its own): same start, same actions -> the same observations to
    1e-5, rewards in float32, identical terminated / truncated flags and final observations."""
    kwargs = {"reset_noise_scale": 0.0, "max_episode_steps": limit}
    sync = VecEnv.of(env_id, 3, **kwargs)
    pool = EnvpoolVecEnv(env_id, 3, **kwargs)
    try:
        acts = _actions(sync.single_action_space, 50, 3)
        obs_a, a = _run(sync, acts)
        obs_b, b = _run(pool, acts)
        np.testing.assert_allclose(obs_a, obs_b, atol=1e-5)
        assert _assert_same(a, b, atol=1e-5, rtol=1e-5) > 0
        assert any(r[3].any() for r in a)  # a time limit was compared (random actions also fail, below it)
    finally:
        sync.close()
        pool.close()


@pytest.mark.mujoco
@needs_envpool
def test_envpool_seeded_resets_repeat_and_differ_by_seed():
    pool = EnvpoolVecEnv("Hopper-v5", 3)
    try:
        a, _ = pool.reset([1, 2, 3])
        b, _ = pool.reset([1, 2, 3])
        c, _ = pool.reset([3, 2, 1])
        np.testing.assert_array_equal(a, b)
        np.testing.assert_array_equal(a[0], c[2])
        assert not np.array_equal(a[0], a[1])
    finally:
        pool.close()


@pytest.mark.mujoco
@needs_envpool
@pytest.mark.parametrize("env_id", ["Hopper-v5", "Walker2d-v5"])
def test_shipped_expert_scores_within_5_percent_on_envpool(env_id):
    from digail.envs import make_env
    from digail.envs.episodes import play_episodes
    from digail.experts.rl import load_expert

    policy = load_expert(env_id)
    n = 4
    gym_returns = [ep.ret for ep in play_episodes(make_env(env_id), lambda env, o: policy(o), n, seed=10_000)]
    pool = EnvpoolVecEnv(env_id, n)
    try:
        obs, _ = pool.reset([20_000 + i for i in range(n)])
        ret, returns = np.zeros(n), [None] * n
        for _ in range(1000):
            obs, rews, _, _, _, final = pool.step(policy(obs))
            ret += rews
            for i in final:
                if returns[i] is None:
                    returns[i] = ret[i]
                ret[i] = 0.0
            if all(r is not None for r in returns):
                break
    finally:
        pool.close()
    assert all(r is not None for r in returns)
    gym_mean, pool_mean = float(np.mean(gym_returns)), float(np.mean(returns))
    assert abs(pool_mean - gym_mean) <= 0.05 * abs(gym_mean), (gym_mean, pool_mean, gym_returns, returns)


def test_backend_choice_and_validation():
    assert resolve_backend("digail/CircleWorld-v0") == "sync"
    assert resolve_backend("digail/FourRooms-v0") == "sync"
    assert resolve_backend("digail/CircleWorld-v0", "subproc") == "subproc"
    if envpool_available():
        assert resolve_backend("Hopper-v5") == "envpool"
    with pytest.raises(UserError, match="envpool"):
        resolve_backend("digail/CircleWorld-v0", "envpool")
    with pytest.raises(UserError, match="backend"):
        TrainConfig(backend="threads")  # type: ignore[arg-type]
    with pytest.raises(UserError, match="env-workers"):
        TrainConfig(env_workers=-1)


def test_dead_worker_is_a_clear_error():
    sub = SubprocVecEnv("digail/CircleWorld-v0", 4, workers=2)
    try:
        sub.reset([0, 1, 2, 3])
        os.kill(sub.processes[1].pid, signal.SIGKILL)
        sub.processes[1].join(timeout=10)
        with pytest.raises(RuntimeError, match=r"worker 1 \(envs 2-3 of digail/CircleWorld-v0\) died"):
            sub.step(np.zeros((4, 2), np.float32))
        assert not any(p.is_alive() for p in sub.processes)  # the others were stopped
    finally:
        sub.close()


def test_close_stops_workers():
    sub = make_vec_env("digail/CircleWorld-v0", 3, "subproc", workers=3)
    procs = list(sub.processes)  # type: ignore[attr-defined]
    sub.close()
    deadline = time.time() + 10
    while time.time() < deadline and any(p.is_alive() for p in procs):
        time.sleep(0.05)
    assert not any(p.is_alive() for p in procs)


# --------------------------------------------------------------------------------------- trainer on each
def _hopper_trainer(backend: str, seed: int = 0):
    from dataclasses import replace

    import gymnasium as gym

    from digail.algos.gail import GAIL
    from digail.data.minari_io import load_dataset
    from digail.nets.policy import ActionSpec
    from digail.nets.vae import HierarchicalPolicy
    from digail.preset import get_preset

    demos = load_dataset("digail/hopper/expert-v0").trajs[:3]
    cfg = replace(get_preset("smoke").train, backend=backend, method="gail")
    space = gym.spaces.Box(-1.0, 1.0, (3,), np.float32)
    torch.manual_seed(seed)
    model = HierarchicalPolicy(11, 1, ActionSpec.from_space(space))
    model.normalizer.fit(np.concatenate([np.asarray(t.obs, np.float32) for t in demos]))
    return GAIL("Hopper-v5", demos, model, cfg, seed=seed, progress=False)


def _train_and_resume(backend: str, tmp_path) -> dict[str, torch.Tensor]:
    """Two smoke iterations, a checkpoint after the first and a resume from it; the final weights."""
    first = _hopper_trainer(backend)
    try:
        first.train(iterations=1)
        first.save_checkpoint(tmp_path / backend / "checkpoint.pt")
    finally:
        first.close()
    resumed = _hopper_trainer(backend)
    try:
        resumed.load_checkpoint(tmp_path / backend / "checkpoint.pt")
        out = resumed.train(iterations=2)
        assert resumed.iteration == 2 and np.isfinite(out["losses/policy"])
        return {k: v.clone() for k, v in resumed.model.state_dict().items()}
    finally:
        resumed.close()


@pytest.mark.mujoco
@pytest.mark.parametrize("backend", ["subproc", pytest.param("envpool", marks=needs_envpool)])
def test_trainer_and_resume_on_backend(backend, tmp_path):
    """Smoke training with a resume in the middle: subproc gives sync's numbers bit for bit; envpool (its own
    reset noise) gives the same numbers on a second run."""
    got = _train_and_resume(backend, tmp_path / "a")
    want = _train_and_resume("sync" if backend == "subproc" else backend, tmp_path / "b")
    for k in want:
        torch.testing.assert_close(got[k], want[k], rtol=0, atol=0, msg=k)


@pytest.mark.mujoco
@pytest.mark.parametrize("backend", ["sync", "subproc", pytest.param("envpool", marks=needs_envpool)])
def test_cli_train_smoke_on_backend(backend, tmp_path):
    import json

    from digail.cli import main

    run = tmp_path / backend
    assert main(["train", "--method", "gail", "--demos", "digail/hopper/expert-v0", "--preset", "smoke",
                 "--train.backend", backend, "--out", str(run)]) == 0
    assert json.loads((run / "config.json").read_text())["train"]["backend"] == backend
    assert (run / "model.pt").exists()


def test_ctrl_c_leaves_the_workers_to_the_trainer():
    """SIGINT to the process group must not kill the workers: the trainer unwinds, then closes them."""
    sub = SubprocVecEnv("digail/CircleWorld-v0", 2, workers=2)
    try:
        sub.reset([0, 1])
        for p in sub.processes:
            os.kill(p.pid, signal.SIGINT)
        time.sleep(0.5)
        obs, *_ = sub.step(np.zeros((2, 2), np.float32))
        assert obs.shape == (2, 2)
    finally:
        sub.close()
