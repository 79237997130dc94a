"""Demonstrations from other tools: each layout written here the way that tool writes it (key names, dtypes,
shapes, episode marks), read back step for step, written as a Minari dataset with the right spaces; a malformed
file of each layout gives one sentence; `digail import` and `digail run ENV --demos FILE` on the command line."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import gymnasium as gym
import h5py
import numpy as np
import pytest

from digail.cli import main
from digail.data.importers import (
    import_demonstrations,
    read_demonstrations,
    trajectories_from_objects,
)
from digail.data.minari_io import load_dataset
from digail.data.trajectory import Trajectory
from digail.envs import make_env
from digail.errors import UserError

PENDULUM = "Pendulum-v1"
CARTPOLE = "CartPole-v1"


@pytest.fixture(scope="module")
def pendulum_trajs() -> list[Trajectory]:
    """Three short continuous episodes of the shipped Pendulum demonstrations (cut to 40 steps: truncated)."""
    ds = load_dataset("digail/pendulum/expert-v0")
    return [Trajectory(obs=t.obs[:41], acts=t.acts[:40], rews=t.rews[:40] if t.rews is not None else None)
            for t in ds.trajs[:3]]


@pytest.fixture(scope="module")
def cartpole_trajs() -> list[Trajectory]:
    """Four seeded random CartPole episodes (discrete actions; most end by termination)."""
    env = make_env(CARTPOLE)
    rng = np.random.default_rng(0)
    trajs = []
    for i in range(4):
        obs, _ = env.reset(seed=i)
        o, a, r = [obs], [], []
        done = term = False
        while not done:
            act = int(rng.integers(2))
            obs, rew, term, trunc, _ = env.step(act)
            o.append(obs)
            a.append(act)
            r.append(rew)
            done = term or trunc
        trajs.append(Trajectory(obs=np.asarray(o, np.float32), acts=np.asarray(a, np.int64),
                                rews=np.asarray(r, np.float32), terminated=bool(term)))
    env.close()
    return trajs


def assert_one_sentence(exc: pytest.ExceptionInfo[UserError], *phrases: str) -> None:
    msg = str(exc.value)
    assert "\n" not in msg and msg.rstrip().endswith("."), msg
    for phrase in phrases:
        assert phrase in msg, msg


# ------------------------------------------------------------------------------------ how each tool writes
def save_like_sb_generate_expert_traj(path: Path, trajs: list[Trajectory], discrete: bool) -> None:
    """Stable-Baselines' `generate_expert_traj`: one row per step (no state after the last action), Discrete actions
    reshaped to (N, 1), `episode_starts` True on each episode's first row, `episode_returns` per episode."""
    acts = np.concatenate([t.acts for t in trajs])
    np.savez(path, actions=acts.reshape(-1, 1) if discrete else acts,
             obs=np.concatenate([t.obs[:-1] for t in trajs]),
             rewards=np.concatenate([t.rews for t in trajs]),
             episode_returns=np.array([t.rews.sum() for t in trajs]),
             episode_starts=np.concatenate([np.arange(len(t)) == 0 for t in trajs]))


def save_like_imitation(path: Path, trajs: list[Trajectory]) -> None:
    """imitation's `types.save` of `TrajectoryWithRew`s: T + 1 observations per trajectory back to back, `indices`
    the cumulative lengths, one `terminal` flag each, and `infos` as an object array (pickled by numpy)."""
    np.savez_compressed(path, obs=np.concatenate([t.obs for t in trajs]),
                        acts=np.concatenate([t.acts for t in trajs]),
                        infos=np.concatenate([np.full(len(t), {}) for t in trajs]),
                        terminal=np.array([t.terminated for t in trajs]),
                        indices=np.cumsum([len(t) for t in trajs[:-1]]),
                        rews=np.concatenate([t.rews for t in trajs]))


def d4rl_arrays(trajs: list[Trajectory], tail: int = 0) -> dict[str, np.ndarray]:
    """D4RL's `env.get_dataset()`: flat float32 transitions, bool `terminals` on a terminating step and `timeouts`
    on a time-limited one, the next episode's reset right after (no next state stored); `tail` extra steps of an
    episode the file cuts off."""
    obs, acts, rews, terms, touts = [], [], [], [], []
    for t in trajs:
        n = len(t)
        obs.append(t.obs[:-1])
        acts.append(t.acts)
        rews.append(t.rews)
        terms.append(np.arange(n) == n - 1 if t.terminated else np.zeros(n, bool))
        touts.append(np.zeros(n, bool) if t.terminated else np.arange(n) == n - 1)
    if tail:
        obs.append(trajs[0].obs[:tail])
        acts.append(trajs[0].acts[:tail])
        rews.append(trajs[0].rews[:tail])
        terms.append(np.zeros(tail, bool))
        touts.append(np.zeros(tail, bool))
    return {"observations": np.concatenate(obs).astype(np.float32),
            "actions": np.concatenate(acts).astype(np.float32),
            "rewards": np.concatenate(rews).astype(np.float32),
            "terminals": np.concatenate(terms), "timeouts": np.concatenate(touts)}


def save_like_d4rl_hdf5(path: Path, data: dict[str, np.ndarray]) -> None:
    """D4RL's HDF5 files: the arrays at the top level, plus an `infos/` group and `metadata/` attributes."""
    with h5py.File(path, "w") as f:
        for key, value in data.items():
            f.create_dataset(key, data=value, compression="gzip")
        f.create_dataset("infos/qpos", data=np.zeros((len(data["actions"]), 2), np.float32))
        f.attrs["metadata/algorithm"] = "SAC"


# ----------------------------------------------------------------------------------------- reading back
def test_sb_expert_traj_continuous(tmp_path: Path, pendulum_trajs: list[Trajectory]) -> None:
    file = tmp_path / "expert_pendulum.npz"
    save_like_sb_generate_expert_traj(file, pendulum_trajs, discrete=False)
    imported = read_demonstrations(file)
    assert imported.fmt == "sb3" and len(imported.trajs) == 3
    for got, want in zip(imported.trajs, pendulum_trajs, strict=True):
        # no state after the last action is stored: that action goes, the rest is the recorded episode
        np.testing.assert_array_equal(got.obs, want.obs[:-1])
        np.testing.assert_array_equal(got.acts, want.acts[:-1])
        np.testing.assert_array_equal(got.rews, want.rews[:-1])
        assert not got.terminated
    assert imported.notes and "dropped" in imported.notes[0]


def test_sb_expert_traj_discrete_with_next_obs(tmp_path: Path, cartpole_trajs: list[Trajectory]) -> None:
    """Discrete (N, 1) int actions become indices; with `next_obs` every step is kept."""
    file = tmp_path / "expert_cartpole.npz"
    save_like_sb_generate_expert_traj(file, cartpole_trajs, discrete=True)
    with np.load(file) as f:
        data = dict(f)
    data["next_obs"] = np.concatenate([t.obs[1:] for t in cartpole_trajs])
    np.savez(file, **data)
    imported = read_demonstrations(file)
    assert [len(t) for t in imported.trajs] == [len(t) for t in cartpole_trajs]
    for got, want in zip(imported.trajs, cartpole_trajs, strict=True):
        np.testing.assert_array_equal(got.obs, want.obs)
        assert got.acts.dtype == np.int64 and got.acts.ndim == 1
        np.testing.assert_array_equal(got.acts, want.acts)
    assert imported.action_space == gym.spaces.Discrete(2) and not imported.notes


def test_sb3_rollout_buffer_columns(tmp_path: Path, cartpole_trajs: list[Trajectory]) -> None:
    """SB3's rollout buffer: (steps, envs) arrays, one stream per env, each cut at its episode starts; a column that
    begins mid-episode (the buffer's first row continues the last rollout) starts a piece of its own."""
    a, b = cartpole_trajs[0], cartpole_trajs[1]

    def column(first: Trajectory, skip: int, second: Trajectory) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        obs = np.concatenate([first.obs[skip:-1], second.obs[:-1]])
        acts = np.concatenate([first.acts[skip:], second.acts])
        starts = np.concatenate([np.arange(skip, len(first)) == 0, np.arange(len(second)) == 0])
        return obs, acts, starts

    n = min(len(a) + len(b), len(b) - 3 + len(a))
    cols = [column(a, 0, b), column(b, 3, a)]
    np.savez(tmp_path / "buffer.npz", obs=np.stack([c[0][:n] for c in cols], 1),
             actions=np.stack([c[1][:n] for c in cols], 1)[..., None],
             episode_starts=np.stack([c[2][:n] for c in cols], 1).astype(np.float32))  # SB3 keeps floats
    imported = read_demonstrations(tmp_path / "buffer.npz")
    lengths = [len(t) + 1 for t in imported.trajs]  # + the dropped last step of each piece
    assert lengths == [len(a), n - len(a), len(b) - 3, n - (len(b) - 3)]
    np.testing.assert_array_equal(imported.trajs[2].obs, b.obs[3:len(b)])
    np.testing.assert_array_equal(imported.trajs[3].acts, a.acts[:len(imported.trajs[3])])


def test_imitation_npz_never_unpickles_infos(tmp_path: Path, cartpole_trajs: list[Trajectory]) -> None:
    file = tmp_path / "rollouts.npz"
    save_like_imitation(file, cartpole_trajs)
    with pytest.raises(ValueError):  # the file does hold a pickled array: reading it would need allow_pickle
        np.load(file, allow_pickle=False)["infos"]
    imported = read_demonstrations(file)
    assert imported.fmt == "imitation"
    for got, want in zip(imported.trajs, cartpole_trajs, strict=True):
        np.testing.assert_array_equal(got.obs, want.obs)
        np.testing.assert_array_equal(got.acts, want.acts)
        np.testing.assert_array_equal(got.rews, want.rews)
        assert got.terminated == want.terminated
    assert any(t.terminated for t in imported.trajs)


@dataclass(frozen=True)
class TrajectoryWithRew:
    """The fields of imitation's `TrajectoryWithRew`, as a user's list of them has."""

    obs: np.ndarray
    acts: np.ndarray
    infos: np.ndarray | None
    terminal: bool
    rews: np.ndarray


def test_imitation_trajectory_objects(cartpole_trajs: list[Trajectory]) -> None:
    items = [TrajectoryWithRew(t.obs, t.acts, None, t.terminated, t.rews) for t in cartpole_trajs]
    trajs = trajectories_from_objects(items)
    assert [t.terminated for t in trajs] == [t.terminated for t in cartpole_trajs]
    np.testing.assert_array_equal(trajs[1].obs, cartpole_trajs[1].obs)
    bad = [TrajectoryWithRew(t.obs[:-1], t.acts, None, t.terminal, t.rews) for t in items]
    with pytest.raises(UserError) as exc:
        trajectories_from_objects(bad)
    assert_one_sentence(exc, "trajectory 0", "one more observation than actions")


def test_d4rl_hdf5_terminals_and_timeouts(tmp_path: Path, cartpole_trajs: list[Trajectory]) -> None:
    """An episode ends after a step flagged by `terminals` or `timeouts`; the tail the file cuts off is kept as a
    truncated episode; without next states each episode's last action is dropped."""
    trajs = [cartpole_trajs[0], Trajectory(obs=cartpole_trajs[1].obs[:11], acts=cartpole_trajs[1].acts[:10],
                                           rews=cartpole_trajs[1].rews[:10])]  # a timeout after 10 steps
    file = tmp_path / "hopper-medium-v2.hdf5"
    save_like_d4rl_hdf5(file, d4rl_arrays(trajs, tail=5))
    imported = read_demonstrations(file)
    assert imported.fmt == "d4rl"
    assert [len(t) for t in imported.trajs] == [len(trajs[0]) - 1, 9, 4]
    np.testing.assert_array_equal(imported.trajs[1].obs, trajs[1].obs[:10])
    assert imported.trajs[0].acts.dtype == np.float32  # D4RL stores every action as float32
    assert any("truncated episode" in n for n in imported.notes)


def test_d4rl_dict_with_next_observations(cartpole_trajs: list[Trajectory]) -> None:
    """`qlearning_dataset`-style dicts carry `next_observations`: every step is kept and terminals are kept."""
    data = d4rl_arrays(cartpole_trajs)
    data["next_observations"] = np.concatenate([t.obs[1:] for t in cartpole_trajs])
    imported = read_demonstrations(data)
    assert [len(t) for t in imported.trajs] == [len(t) for t in cartpole_trajs]
    assert [t.terminated for t in imported.trajs] == [t.terminated for t in cartpole_trajs]
    np.testing.assert_array_equal(imported.trajs[3].obs, cartpole_trajs[3].obs)
    assert not imported.notes


@pytest.mark.parametrize("with_final_obs", [True, False])
def test_plain_arrays_with_episode_ends(tmp_path: Path, pendulum_trajs: list[Trajectory],
                                        with_final_obs: bool) -> None:
    obs = np.concatenate([t.obs if with_final_obs else t.obs[:-1] for t in pendulum_trajs])
    np.savez(tmp_path / "mine.npz", observations=obs, actions=np.concatenate([t.acts for t in pendulum_trajs]),
             episode_ends=np.cumsum([len(t) for t in pendulum_trajs]))
    imported = read_demonstrations(tmp_path / "mine.npz")
    assert imported.fmt == "arrays"
    keep = 0 if with_final_obs else 1
    for got, want in zip(imported.trajs, pendulum_trajs, strict=True):
        np.testing.assert_array_equal(got.obs, want.obs[:len(want.obs) - keep])
        assert got.rews is None
    assert bool(imported.notes) != with_final_obs


# -------------------------------------------------------------------------------------------- malformed
def _sb(trajs: list[Trajectory]) -> dict[str, np.ndarray]:
    return {"obs": np.concatenate([t.obs[:-1] for t in trajs]), "actions": np.concatenate([t.acts for t in trajs]),
            "episode_starts": np.concatenate([np.arange(len(t)) == 0 for t in trajs])}


def _imitation(trajs: list[Trajectory]) -> dict[str, np.ndarray]:
    return {"obs": np.concatenate([t.obs for t in trajs]), "acts": np.concatenate([t.acts for t in trajs]),
            "terminal": np.array([t.terminated for t in trajs]), "indices": np.cumsum([len(t) for t in trajs[:-1]])}


def _arrays(trajs: list[Trajectory]) -> dict[str, np.ndarray]:
    return {"observations": np.concatenate([t.obs for t in trajs]),
            "actions": np.concatenate([t.acts for t in trajs]), "episode_ends": np.cumsum([len(t) for t in trajs])}


def _nan(key: str):  # noqa: ANN202
    def f(d: dict[str, np.ndarray]) -> None:
        d[key] = d[key].astype(np.float32)
        d[key][3] = np.nan
    return f


BROKEN = {  # layout -> how it is broken -> (change, phrases of the sentence)
    "sb3 missing": (_sb, lambda d: d.pop("episode_starts"), ("holds actions, obs", "none of the layouts")),
    "sb3 missing actions": (_sb, lambda d: d.pop("actions"), ("no 'actions' array",)),
    "sb3 ragged": (_sb, lambda d: d.update(actions=d["actions"][:-2]), ("rows of 'actions'", "matching lengths")),
    "sb3 nan": (_sb, _nan("obs"), ("NaN or inf", "'obs'")),
    "sb3 strings": (_sb, lambda d: d.update(actions=d["actions"].astype(str)), ("'actions' of dtype",)),
    "sb3 starts": (_sb, lambda d: d.update(episode_starts=d["episode_starts"] * 2), ("True/False",)),
    "imitation missing": (_imitation, lambda d: d.pop("terminal"), ("no 'terminal' array",)),
    "imitation ragged": (_imitation, lambda d: d.update(obs=d["obs"][:-1]), ("one more observation",)),
    "imitation nan": (_imitation, _nan("obs"), ("NaN or inf",)),
    "imitation indices": (_imitation, lambda d: d.update(indices=d["indices"].astype(np.float64)),
                          ("integer indices",)),
    "imitation order": (_imitation, lambda d: d.update(indices=d["indices"][::-1].copy()), ("strictly increasing",)),
    "imitation pickled obs": (_imitation, lambda d: d.update(obs=np.array(list(d["obs"]) + [None], dtype=object)),
                              ("pickled Python objects",)),
    "d4rl missing": (d4rl_arrays, lambda d: d.pop("actions"), ("no 'actions' array",)),
    "d4rl no ends": (d4rl_arrays, lambda d: (d.pop("terminals"), d.pop("timeouts")), ("holds actions",)),
    "d4rl ragged": (d4rl_arrays, lambda d: d.update(timeouts=d["timeouts"][1:]), ("rows of 'timeouts'",)),
    "d4rl nan": (d4rl_arrays, _nan("rewards"), ("NaN or inf", "'rewards'")),
    "d4rl flags": (d4rl_arrays, lambda d: d.update(terminals=d["terminals"] * 3), ("True/False",)),
    "d4rl strings": (d4rl_arrays, lambda d: d.update(observations=d["observations"].astype(str)),
                     ("'observations' of dtype",)),
    "arrays ends dtype": (_arrays, lambda d: d.update(episode_ends=d["episode_ends"].astype(np.float32)),
                          ("integer indices",)),
    "arrays missing": (_arrays, lambda d: d.pop("observations"), ("no 'observations' array",)),
    "arrays ends": (_arrays, lambda d: d.update(episode_ends=d["episode_ends"] - 1), ("episode_ends",)),
    "arrays ragged": (_arrays, lambda d: d.update(observations=d["observations"][:-2]), ("observations for",)),
    "arrays nan": (_arrays, _nan("actions"), ("NaN or inf",)),
}


@pytest.mark.parametrize("case", sorted(BROKEN))
def test_malformed_file(tmp_path: Path, cartpole_trajs: list[Trajectory], case: str) -> None:
    make, breaks, phrases = BROKEN[case]
    data = make(cartpole_trajs)
    breaks(data)
    file = tmp_path / "bad.npz"
    np.savez(file, **data)
    with pytest.raises(UserError) as exc:
        read_demonstrations(file, case.split()[0] if "missing" in case and case != "sb3 missing" else "auto")
    assert_one_sentence(exc, str(file), *phrases)


def test_malformed_d4rl_hdf5(tmp_path: Path, cartpole_trajs: list[Trajectory]) -> None:
    data = d4rl_arrays(cartpole_trajs)
    data["observations"][7, 2] = np.nan
    save_like_d4rl_hdf5(tmp_path / "bad.hdf5", data)
    with pytest.raises(UserError) as exc:
        read_demonstrations(tmp_path / "bad.hdf5")
    assert_one_sentence(exc, "bad.hdf5", "NaN or inf", "'observations'")
    data["observations"][7, 2] = 0.0
    del data["timeouts"], data["terminals"]
    save_like_d4rl_hdf5(tmp_path / "bad.hdf5", data)
    with pytest.raises(UserError) as exc:
        read_demonstrations(tmp_path / "bad.hdf5", "d4rl")
    assert_one_sentence(exc, "neither 'terminals' nor 'timeouts'")


def test_unreadable_files(tmp_path: Path) -> None:
    (tmp_path / "junk.npz").write_bytes(b"not a zip")
    (tmp_path / "junk.hdf5").write_bytes(b"not hdf5")
    np.save(tmp_path / "one.npy", np.zeros(3))
    for name, phrase in (("junk.npz", "cannot read"), ("junk.hdf5", "cannot read"), ("none.npz", "no file"),
                         ("one.npy", "neither an .npz nor an HDF5")):
        with pytest.raises(UserError) as exc:
            read_demonstrations(tmp_path / name)
        assert_one_sentence(exc, phrase)


# ------------------------------------------------------------------------------------- written as Minari
def test_import_with_env_stores_its_spaces(tmp_path: Path, pendulum_trajs: list[Trajectory]) -> None:
    file = tmp_path / "mine.npz"
    save_like_sb_generate_expert_traj(file, pendulum_trajs, discrete=False)
    path, _ = import_demonstrations(file, tmp_path / "ds", env_id=PENDULUM)
    ds = load_dataset(path)
    env = make_env(PENDULUM)
    assert ds.env_id == PENDULUM and ds.observation_space == env.observation_space
    assert ds.action_space == env.action_space
    assert len(ds.trajs) == 3 and ds.trajs[0].rews is not None
    with pytest.raises(UserError) as exc:
        import_demonstrations(file, tmp_path / "ds2", env_id=CARTPOLE)
    assert_one_sentence(exc, "observations of shape (3,)", CARTPOLE)
    assert not (tmp_path / "ds2").exists()


def test_import_without_env_takes_spaces_from_data(tmp_path: Path, cartpole_trajs: list[Trajectory]) -> None:
    file = tmp_path / "rollouts.npz"
    save_like_imitation(file, cartpole_trajs)
    path, _ = import_demonstrations(file, tmp_path / "ds")
    ds = load_dataset(path)
    assert ds.env_id is None
    assert ds.observation_space == gym.spaces.Box(-np.inf, np.inf, (4,), np.float32)
    assert ds.action_space == gym.spaces.Discrete(2)
    assert [t.terminated for t in ds.trajs] == [t.terminated for t in cartpole_trajs]


def test_cli_import(tmp_path: Path, capsys: pytest.CaptureFixture[str], pendulum_trajs: list[Trajectory]) -> None:
    file = tmp_path / "expert.npz"
    save_like_sb_generate_expert_traj(file, pendulum_trajs, discrete=False)
    assert main(["import", str(file), "--env", PENDULUM, "--out", str(tmp_path / "ds")]) == 0
    assert "imported 3 episodes" in capsys.readouterr().out
    assert load_dataset(tmp_path / "ds").env_id == PENDULUM
    with np.load(file) as f:
        data = dict(f)
    data["obs"][5, 1] = np.inf
    np.savez(file, **data)
    assert main(["import", str(file), "--out", str(tmp_path / "bad")]) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith("digail import: error:") and "NaN or inf" in err and len(err.splitlines()) == 1
    assert not (tmp_path / "bad").exists()
    assert main(["import", str(file), "--dataset-id", "../../escaped-v0"]) == 2
    assert "invalid Minari dataset id" in capsys.readouterr().err


# ------------------------------------------------------------------------------------ the whole pipeline
@pytest.mark.slow
def test_run_with_own_demos(tmp_path: Path, capsys: pytest.CaptureFixture[str],
                            pendulum_trajs: list[Trajectory]) -> None:
    """`digail run ENV --demos FILE` imports the file into RUN/demos and runs every stage on it."""
    file = tmp_path / "mine.npz"
    save_like_sb_generate_expert_traj(file, pendulum_trajs, discrete=False)
    run = tmp_path / "run"
    assert main(["run", PENDULUM, "--demos", str(file), "--preset", "smoke", "--episodes", "2", "--out",
                 str(run)]) == 0
    assert load_dataset(run / "demos").env_id == PENDULUM
    for name in ("model.pt", "eval.json", "segmentation.json", "report.html", "vae/model.pt"):
        assert (run / name).is_file(), name
    assert "3 demonstrations of Pendulum-v1" in capsys.readouterr().out


def test_run_refuses_demos_of_another_env(tmp_path: Path, capsys: pytest.CaptureFixture[str],
                                          pendulum_trajs: list[Trajectory]) -> None:
    """A file that does not fit the env is refused before the run folder exists."""
    file = tmp_path / "mine.npz"
    save_like_sb_generate_expert_traj(file, pendulum_trajs, discrete=False)
    assert main(["run", "InvertedPendulum-v5", "--demos", str(file), "--out", str(tmp_path / "run2")]) == 2
    assert "observations of shape (3,)" in capsys.readouterr().err
    assert not (tmp_path / "run2").exists()


def test_run_without_expert_asks_for_demos(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["run", "MountainCarContinuous-v0", "--out", str(tmp_path / "run")]) == 2
    err = capsys.readouterr().err
    assert "no demonstrations or expert for MountainCarContinuous-v0" in err and "--demos" in err
    assert not (tmp_path / "run").exists()
