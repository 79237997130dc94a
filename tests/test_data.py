"""Minari read/write: round trips, id resolution, atomic writes and every bad-input case (library level)."""

from __future__ import annotations

import dataclasses
import json
import shutil
import warnings
from pathlib import Path

import gymnasium as gym
import h5py
import numpy as np
import pytest

from digail.data import minari_io
from digail.data.minari_io import dataset_env_id, flatten_dict_obs, load_dataset, resolve_dataset
from digail.data.minari_write import write_dataset
from digail.data.trajectory import Trajectory
from digail.data.validation import check_matches_env
from digail.envs import make_env
from digail.envs.episodes import play_episodes
from digail.errors import UserError


def random_trajs(env_id: str, n: int, *, labels: bool = False, seed: int = 0) -> list[Trajectory]:
    """`n` seeded random-action episodes; fake labels `t % 3` when `labels`."""
    env = gym.make(env_id)
    env.action_space.seed(seed)
    episodes = play_episodes(env, lambda env, obs: env.action_space.sample(), n, seed, keep=True)
    trajs = []
    for ep in episodes:
        acts_arr = np.asarray(ep.acts, dtype=np.int64 if np.ndim(ep.acts[0]) == 0 else np.float32)
        trajs.append(Trajectory(obs=np.asarray(ep.obs, np.float32), acts=acts_arr, rews=np.asarray(ep.rews, np.float32),
                                subtasks=np.arange(len(ep.obs)) % 3 if labels else None, terminated=ep.terminated))
    env.close()
    return trajs


@pytest.fixture(scope="module")
def cartpole(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, list[Trajectory]]:
    trajs = random_trajs("CartPole-v1", 4, labels=True)
    path = write_dataset(trajs, tmp_path_factory.mktemp("ds") / "cartpole", "CartPole-v1",
                         "test/cartpole/random-v0", seeds=[0, 1, 2, 3])
    return path, trajs


@pytest.fixture(scope="module")
def pendulum(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, list[Trajectory]]:
    trajs = random_trajs("Pendulum-v1", 2)
    path = write_dataset(trajs, tmp_path_factory.mktemp("ds") / "pendulum", "Pendulum-v1",
                         "test/pendulum/random-v0")
    return path, trajs


def damaged_copy(src: Path, dst: Path) -> Path:
    shutil.copytree(src, dst)
    return dst


def replace_array(path: Path, key: str, value: np.ndarray) -> None:
    with h5py.File(path / "data" / "main_data.hdf5", "a") as f:
        del f[key]
        f.create_dataset(key, data=value)


def assert_one_sentence(exc: pytest.ExceptionInfo[UserError]) -> None:
    message = str(exc.value)
    assert "\n" not in message and message.endswith("."), message


# --------------------------------------------------------------------------------------------- round trip
def test_round_trip_discrete_with_labels(cartpole: tuple[Path, list[Trajectory]]) -> None:
    path, trajs = cartpole
    ds = load_dataset(str(path))
    assert ds.env_id == "CartPole-v1" and ds.dataset_id == "test/cartpole/random-v0"
    assert ds.path == path and ds.has_labels and len(ds.trajs) == 4
    assert isinstance(ds.action_space, gym.spaces.Discrete) and ds.observation_space.shape == (4,)
    for a, b in zip(trajs, ds.trajs, strict=True):
        assert b.acts.dtype == np.int64 and b.obs.dtype == np.float32
        np.testing.assert_array_equal(a.obs, b.obs)
        np.testing.assert_array_equal(a.acts, b.acts)
        np.testing.assert_array_equal(a.rews, b.rews)
        np.testing.assert_array_equal(a.subtasks, b.subtasks)
        assert a.terminated == b.terminated
    assert any(t.terminated for t in ds.trajs)  # random CartPole falls over
    assert ds.num_steps == sum(len(t) for t in trajs)
    import minari

    storage = minari.MinariDataset(path / "data").storage
    seeds = [m["seed"] for m in storage.get_episode_metadata(range(4))]
    assert seeds == [0, 1, 2, 3]


def test_round_trip_continuous_truncated(pendulum: tuple[Path, list[Trajectory]]) -> None:
    path, trajs = pendulum
    ds = load_dataset(path / "data")  # the data/ folder itself is accepted too
    assert not ds.has_labels and ds.trajs[0].acts.dtype == np.float32 and ds.trajs[0].acts.shape == (200, 1)
    assert [t.terminated for t in ds.trajs] == [False, False]
    np.testing.assert_array_equal(trajs[1].acts, ds.trajs[1].acts)
    check_matches_env(ds, "Pendulum-v1")


def test_missing_rewards_round_trip_as_none(tmp_path: Path) -> None:
    traj = random_trajs("CartPole-v1", 1)[0]
    bare = Trajectory(obs=traj.obs, acts=traj.acts, rews=None, terminated=traj.terminated)
    ds = load_dataset(write_dataset([bare], tmp_path / "d", "CartPole-v1", "test/bare-v0"))
    assert ds.trajs[0].rews is None


def test_ids_resolve_in_minari_root(tmp_path: Path, monkeypatch: pytest.MonkeyPatch,
                                    cartpole: tuple[Path, list[Trajectory]]) -> None:
    monkeypatch.setenv("MINARI_DATASETS_PATH", str(tmp_path))
    shutil.copytree(cartpole[0], tmp_path / "test/cartpole/random-v0")
    assert resolve_dataset("test/cartpole/random-v0") == tmp_path / "test/cartpole/random-v0"
    assert dataset_env_id("test/cartpole/random-v0") == "CartPole-v1"
    assert len(load_dataset("test/cartpole/random-v0").trajs) == 4


def test_dict_observations_are_flattened_like_gymnasium(tmp_path: Path,
                                                        monkeypatch: pytest.MonkeyPatch) -> None:
    from minari import create_dataset_from_buffers
    from minari.data_collector import EpisodeBuffer

    space = gym.spaces.Dict({"b": gym.spaces.Box(-1, 1, (2,)), "a": gym.spaces.Box(-1, 1, (3,))})
    rng = np.random.default_rng(0)
    obs = {key: rng.uniform(-1, 1, (6, dim)).astype(np.float32) for key, dim in (("a", 3), ("b", 2))}
    buf = EpisodeBuffer(observations=obs, actions=rng.uniform(-1, 1, (5, 1)).astype(np.float32),
                        rewards=np.zeros(5), terminations=np.zeros(5, bool), truncations=np.arange(5) == 4)
    monkeypatch.setenv("MINARI_DATASETS_PATH", str(tmp_path))
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # Minari's reminders about optional metadata
        create_dataset_from_buffers("test/dict-v0", [buf], observation_space=space,
                                    action_space=gym.spaces.Box(-1, 1, (1,)))
    ds = load_dataset("test/dict-v0")
    expected = np.stack([gym.spaces.flatten(space, {"a": obs["a"][t], "b": obs["b"][t]}) for t in range(6)])
    np.testing.assert_allclose(ds.trajs[0].obs, expected)
    assert ds.observation_space.shape == (5,) and ds.env_id is None
    np.testing.assert_allclose(flatten_dict_obs(obs, space), expected)


# ----------------------------------------------------------------------------------------------- writing
def test_existing_output_needs_force(tmp_path: Path, cartpole: tuple[Path, list[Trajectory]]) -> None:
    trajs = cartpole[1]
    out = write_dataset(trajs[:1], tmp_path / "d", "CartPole-v1", "test/a-v0")
    with pytest.raises(UserError, match="already exists") as exc:
        write_dataset(trajs, out, "CartPole-v1", "test/a-v0")
    assert_one_sentence(exc)
    assert len(load_dataset(out).trajs) == 1
    write_dataset(trajs, out, "CartPole-v1", "test/a-v0", force=True)
    assert len(load_dataset(out).trajs) == 4
    assert sorted(p.name for p in tmp_path.iterdir()) == ["d"]  # no temporary folders left


def test_failed_write_leaves_nothing(tmp_path: Path, monkeypatch: pytest.MonkeyPatch,
                                     cartpole: tuple[Path, list[Trajectory]]) -> None:
    import minari

    def boom(*args: object, **kwargs: object) -> None:
        raise OSError("disk full")

    monkeypatch.setattr(minari, "create_dataset_from_buffers", boom)
    with pytest.raises(OSError, match="disk full"):
        write_dataset(cartpole[1], tmp_path / "d", "CartPole-v1", "test/a-v0")
    assert list(tmp_path.iterdir()) == []


@pytest.mark.parametrize("case", ["float-actions-discrete", "obs-shape", "mixed-labels", "no-episodes",
                                  "bad-id", "unknown-env", "seeds"])
def test_bad_writes(tmp_path: Path, case: str, cartpole: tuple[Path, list[Trajectory]]) -> None:
    trajs = list(cartpole[1])
    env_id, ds_id = "CartPole-v1", "test/a-v0"
    t0 = trajs[0]
    kwargs: dict[str, object] = {}
    if case == "float-actions-discrete":
        trajs[0] = Trajectory(obs=t0.obs, acts=t0.acts.astype(np.float32), subtasks=t0.subtasks)
    elif case == "obs-shape":
        env_id = "Pendulum-v1"
    elif case == "mixed-labels":
        trajs[0] = Trajectory(obs=t0.obs, acts=t0.acts)
    elif case == "no-episodes":
        trajs = []
    elif case == "bad-id":
        ds_id = "not a valid id!"
    elif case == "unknown-env":
        env_id = "NoSuchEnv-v0"
    elif case == "seeds":
        kwargs["seeds"] = [1]
    with pytest.raises(UserError) as exc:
        write_dataset(trajs, tmp_path / "d", env_id, ds_id, **kwargs)  # type: ignore[arg-type]
    assert_one_sentence(exc)
    assert list(tmp_path.iterdir()) == []


# ----------------------------------------------------------------------------------------------- reading
def test_missing_dataset(tmp_path: Path) -> None:
    for target in [tmp_path / "nothing", tmp_path, "nobody/nothing-v0"]:
        with pytest.raises(UserError, match="no Minari dataset at .*digail demos") as exc:
            load_dataset(target)
        assert_one_sentence(exc)
        with pytest.raises(UserError, match="no Minari dataset"):
            dataset_env_id(target)


def test_corrupt_hdf5(tmp_path: Path, cartpole: tuple[Path, list[Trajectory]]) -> None:
    bad = damaged_copy(cartpole[0], tmp_path / "bad")
    (bad / "data" / "main_data.hdf5").write_bytes(b"this is not an HDF5 file")
    with pytest.raises(UserError, match="cannot read the Minari dataset") as exc:
        load_dataset(bad)
    assert_one_sentence(exc)


def test_corrupt_metadata(tmp_path: Path, cartpole: tuple[Path, list[Trajectory]]) -> None:
    bad = damaged_copy(cartpole[0], tmp_path / "bad")
    (bad / "data" / "metadata.json").write_text("{truncated")
    for read in (load_dataset, dataset_env_id):
        with pytest.raises(UserError, match="corrupt") as exc:
            read(bad)
        assert_one_sentence(exc)


def test_no_env_spec(tmp_path: Path, cartpole: tuple[Path, list[Trajectory]]) -> None:
    bad = damaged_copy(cartpole[0], tmp_path / "bad")
    meta = json.loads((bad / "data" / "metadata.json").read_text())
    del meta["env_spec"]
    (bad / "data" / "metadata.json").write_text(json.dumps(meta))
    with pytest.raises(UserError, match="no environment id.*--env"):
        dataset_env_id(bad)
    assert load_dataset(bad).env_id is None


def _nan_obs(obs: np.ndarray) -> np.ndarray:
    obs = obs.copy()
    obs[2, 1] = np.nan
    return obs


@pytest.mark.parametrize("case, match", [
    ("nan-obs", "NaN or inf values in its observations"),
    ("inf-reward", "NaN or inf rewards"),
    ("float-actions", "needs integers"),
    ("action-out-of-range", "outside Discrete"),
    ("obs-shape", r"observations of shape \(3,\)"),
    ("obs-count", "expected one more observation"),
    ("labels-length", "labels of shape"),
    ("labels-float", "labels of dtype float"),
    ("early-termination", "terminates at step 1 before its last step"),
])
def test_bad_discrete_dataset(tmp_path: Path, cartpole: tuple[Path, list[Trajectory]], case: str,
                              match: str) -> None:
    bad = damaged_copy(cartpole[0], tmp_path / "bad")
    traj = cartpole[1][1]
    ep = "episode_1"
    edits = {
        "nan-obs": ("observations", _nan_obs(traj.obs)),
        "inf-reward": ("rewards", np.where(np.arange(len(traj)) == 0, np.inf, traj.rews)),
        "float-actions": ("actions", traj.acts.astype(np.float32)),
        "action-out-of-range": ("actions", traj.acts + 5),
        "obs-shape": ("observations", traj.obs[:, :3]),
        "obs-count": ("observations", traj.obs[:-1]),
        "labels-length": ("infos/subtask", traj.subtasks[:-1]),
        "labels-float": ("infos/subtask", traj.subtasks.astype(np.float64)),
        "early-termination": ("terminations", np.arange(len(traj)) >= 1),
    }
    key, value = edits[case]
    replace_array(bad, f"{ep}/{key}", value)
    with pytest.raises(UserError, match=match) as exc:
        load_dataset(bad)
    assert_one_sentence(exc)
    assert "episode 1" in str(exc.value)


@pytest.mark.parametrize("case, match", [
    ("action-shape", r"actions of shape \(2,\) but the action space has shape \(1,\)"),
    ("nan-action", "NaN or inf values in its actions"),
])
def test_bad_continuous_dataset(tmp_path: Path, pendulum: tuple[Path, list[Trajectory]], case: str,
                                match: str) -> None:
    bad = damaged_copy(pendulum[0], tmp_path / "bad")
    acts = pendulum[1][0].acts
    value = np.concatenate([acts, acts], axis=1) if case == "action-shape" else np.full_like(acts, np.nan)
    replace_array(bad, "episode_0/actions", value)
    with pytest.raises(UserError, match=match) as exc:
        load_dataset(bad)
    assert_one_sentence(exc)


def test_partial_labels(tmp_path: Path, cartpole: tuple[Path, list[Trajectory]]) -> None:
    bad = damaged_copy(cartpole[0], tmp_path / "bad")
    with h5py.File(bad / "data" / "main_data.hdf5", "a") as f:
        del f["episode_2/infos"]
    with pytest.raises(UserError, match="labels in 3 of 4 episodes") as exc:
        load_dataset(bad)
    assert_one_sentence(exc)


# ---------------------------------------------------------------------------------------------- envs
def test_dataset_env_mismatch(cartpole: tuple[Path, list[Trajectory]],
                              pendulum: tuple[Path, list[Trajectory]]) -> None:
    cp, pd = load_dataset(cartpole[0]), load_dataset(pendulum[0])
    check_matches_env(cp, "CartPole-v1")
    with pytest.raises(UserError, match=r"observations of shape \(3,\) but CartPole-v1") as exc:
        check_matches_env(pd, "CartPole-v1")
    assert_one_sentence(exc)
    three_actions = dataclasses.replace(cp, action_space=gym.spaces.Discrete(3))
    with pytest.raises(UserError, match=r"action space Discrete\(3\) but CartPole-v1 has Discrete") as exc:
        check_matches_env(three_actions, "CartPole-v1")
    assert_one_sentence(exc)


@pytest.mark.parametrize("env_id, match", [
    ("NoSuchEnv-v0", "known ids include digail/FourRooms-v0"),
    ("Pendulum-v9", "did you mean Pendulum-v1"),
    ("nobody/Thing-v0", "unknown environment id"),
    ("digail/FourRoom-v0", "did you mean digail/FourRooms-v0"),
])
def test_unknown_env_ids(env_id: str, match: str) -> None:
    with pytest.raises(UserError, match=match) as exc:
        make_env(env_id)
    assert_one_sentence(exc)


def test_make_env_known() -> None:
    env = make_env("digail/CircleWorld-v0")
    assert env.action_space.shape == (2,)
    env.close()


def test_shipped_root_is_inside_package() -> None:
    assert minari_io.SHIPPED_ROOT.name == "datasets" and minari_io.SHIPPED_ROOT.parent.name == "digail"
