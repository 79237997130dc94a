"""`digail demos`, bad datasets through the CLI, and the datasets shipped with the package."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import numpy as np
import pytest

from digail.cli import main
from digail.data.demos import (
    build_manifest,
    default_dataset_id,
    record_demos,
    rollout_episodes,
)
from digail.data.minari_io import SHIPPED_ROOT, dataset_env_id, load_dataset, shipped_dataset_ids
from digail.data.minari_write import write_dataset
from digail.data.validation import check_matches_env
from digail.envs import make_env
from digail.envs.registry import ENV_SPECS
from digail.errors import UserError
from digail.experts.scripted import get_scripted_expert


def run_cli(capsys: pytest.CaptureFixture[str], *argv: str) -> tuple[int, str]:
    """Exit status and stderr of `digail ARGV`."""
    capsys.readouterr()
    code = main(list(argv))
    return code, capsys.readouterr().err


def assert_one_line_error(code: int, err: str, match: str) -> None:
    assert code == 2
    lines = [line for line in err.splitlines() if line.strip()]
    assert len(lines) == 1, err
    assert lines[0].startswith("digail ") and "error:" in lines[0] and match in lines[0], lines[0]


# ------------------------------------------------------------------------------------------------ demos
def test_demos_cli_round_trip_and_reproducible(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    out = tmp_path / "cw"
    code, _ = run_cli(capsys, "demos", "digail/CircleWorld-v0", "--episodes", "3", "--seed", "7",
                      "--out", str(out))
    assert code == 0
    ds = load_dataset(out)
    assert ds.env_id == "digail/CircleWorld-v0" and ds.dataset_id == "digail/circleworld/expert-v0"
    assert len(ds.trajs) == 3 and all(len(t) == 120 and not t.terminated for t in ds.trajs)
    labels = ds.trajs[0].subtasks
    assert labels is not None and set(labels.tolist()) == {0, 1} and labels[0] == 0 and labels[-1] == 1
    assert ds.metadata["digail"]["seed"] == 7 and ds.metadata["digail"]["expert"] == "scripted"
    # the same command gives the same data; another seed gives other radii
    again = load_dataset(record_demos("digail/CircleWorld-v0", episodes=3, seed=7, out=tmp_path / "again"))
    other = load_dataset(record_demos("digail/CircleWorld-v0", episodes=1, seed=8, out=tmp_path / "other"))
    for a, b in zip(ds.trajs, again.trajs, strict=True):
        np.testing.assert_array_equal(a.obs, b.obs)
        np.testing.assert_array_equal(a.acts, b.acts)
    np.testing.assert_array_equal(ds.trajs[1].obs, other.trajs[0].obs)  # episode i uses seed + i
    assert not np.array_equal(ds.trajs[0].obs, other.trajs[0].obs)


def test_demos_existing_output_needs_force(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    out = tmp_path / "fr"
    assert run_cli(capsys, "demos", "digail/FourRooms-v0", "--episodes", "2", "--out", str(out))[0] == 0
    before = (out / "data" / "main_data.hdf5").read_bytes()
    code, err = run_cli(capsys, "demos", "digail/FourRooms-v0", "--episodes", "3", "--out", str(out))
    assert_one_line_error(code, err, "already exists")
    assert (out / "data" / "main_data.hdf5").read_bytes() == before
    code, _ = run_cli(capsys, "demos", "digail/FourRooms-v0", "--episodes", "3", "--out", str(out), "--force")
    assert code == 0
    ds = load_dataset(out)
    assert len(ds.trajs) == 3 and all(t.terminated for t in ds.trajs) and ds.trajs[0].acts.dtype == np.int64
    assert sorted(p.name for p in tmp_path.iterdir()) == ["fr"]


@pytest.mark.parametrize("argv, match", [
    (["NoSuchEnv-v0", "--episodes", "2"], "unknown environment id"),
    (["digail/CircleWorld-v0", "--episodes", "0"], "--episodes must be at least 1"),
    (["CartPole-v1"], "no default number of episodes for CartPole-v1"),
    (["CartPole-v1", "--episodes", "1"], "CartPole-v1"),  # neither a scripted nor a shipped RL expert
    (["Pendulum-v1", "--episodes", "1", "--expert", "/nonexistent/expert.pt"], "/nonexistent/expert.pt"),
])
def test_demos_bad_input(tmp_path: Path, capsys: pytest.CaptureFixture[str], argv: list[str],
                         match: str) -> None:
    out = tmp_path / "out"
    code, err = run_cli(capsys, "demos", *argv, "--out", str(out))
    assert_one_line_error(code, err, match)
    assert list(tmp_path.iterdir()) == []


def test_demos_with_rl_expert(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """Non-digail envs use `digail.experts.rl.load_expert` (a batch policy); here a constant stand-in."""
    import digail.experts.rl as rl

    calls: list[tuple[str, object]] = []

    def fake_load_expert(env_id: str, path: object = None):  # type: ignore[no-untyped-def]
        calls.append((env_id, path))
        return lambda obs: np.full((len(obs), 1), 0.5, dtype=np.float32)

    monkeypatch.setattr(rl, "load_expert", fake_load_expert)
    monkeypatch.setenv("MINARI_DATASETS_PATH", str(tmp_path))
    path = record_demos("Pendulum-v1", episodes=2)  # default out: the Minari root / dataset id
    assert path == tmp_path / "digail/pendulum/expert-v0" and calls == [("Pendulum-v1", None)]
    ds = load_dataset(path)  # by path: the id would resolve to the shipped dataset first
    assert not ds.has_labels and len(ds.trajs) == 2 and ds.trajs[0].acts.shape == (200, 1)
    assert np.all(ds.trajs[0].acts == 0.5) and ds.metadata["digail"]["expert"] == "rl"
    check_matches_env(ds, "Pendulum-v1")


def test_default_sizes_and_ids() -> None:
    assert ENV_SPECS["digail/FourRooms-v0"].demo_episodes == 300
    assert ENV_SPECS["digail/CircleWorld-v0"].demo_episodes == 100
    assert ENV_SPECS["Hopper-v5"].demo_episodes == 50 and ENV_SPECS["Pendulum-v1"].demo_episodes == 25
    assert default_dataset_id("Hopper-v5") == "digail/hopper/expert-v0"
    assert default_dataset_id("digail/FourRooms-v0") == "digail/fourrooms/expert-v0"
    with pytest.raises(UserError):
        record_demos("digail/CircleWorld-v0", episodes=1, seed=-1, out="/nonexistent/never")


# ------------------------------------------------------------------------------- bad datasets via the CLI
@pytest.fixture(scope="module")
def good_dataset(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return record_demos("digail/FourRooms-v0", episodes=3, out=tmp_path_factory.mktemp("good") / "fr")


@pytest.mark.parametrize("case, match", [
    ("missing", "no Minari dataset at"),
    ("corrupt-hdf5", "cannot read the Minari dataset"),
    ("nan", "NaN or inf values in its observations"),
    ("float-actions", "needs integers"),
])
def test_pretrain_reports_bad_datasets(tmp_path: Path, capsys: pytest.CaptureFixture[str], good_dataset: Path,
                                       case: str, match: str) -> None:
    pytest.importorskip("digail.algos.vae_pretrain")
    pytest.importorskip("digail.eval.segmentation")  # imported by `digail pretrain` before it reads the data
    import h5py

    bad = tmp_path / "bad"
    if case != "missing":
        shutil.copytree(good_dataset, bad)
        file = bad / "data" / "main_data.hdf5"
        if case == "corrupt-hdf5":
            file.write_bytes(b"\x00" * 64)
        else:
            with h5py.File(file, "a") as f:
                key = "episode_0/observations" if case == "nan" else "episode_0/actions"
                value = f[key][()].astype(np.float32)
                if case == "nan":
                    value[0, 0] = np.nan
                del f[key]
                f.create_dataset(key, data=value)
    run = tmp_path / "run"
    code, err = run_cli(capsys, "pretrain", "--demos", str(bad), "--out", str(run), "--preset", "smoke")
    assert_one_line_error(code, err, match)
    assert not run.exists()


def test_four_rooms_dataset_does_not_match_circle_world(good_dataset: Path) -> None:
    """A Four Rooms dataset cannot train a Circle-World policy."""
    with pytest.raises(UserError, match="FourRooms-v0.*CircleWorld-v0|observations of shape"):
        check_matches_env(load_dataset(good_dataset), "digail/CircleWorld-v0")


# ----------------------------------------------------------------------------------------- shipped data
ORACLE_LABELS = {"digail/FourRooms-v0": {0, 1, 2, 3, 4}, "digail/CircleWorld-v0": {0, 1},
                 "digail/LandmarkRoute-v0": {0, 1, 2, 3}}
"""Label sets the shipped datasets of envs with an oracle must cover completely."""


def test_default_datasets_are_shipped() -> None:
    assert {"digail/fourrooms/expert-v0", "digail/circleworld/expert-v0"} <= set(shipped_dataset_ids())


def _shipped_params() -> list[object]:
    """One case per shipped dataset; MuJoCo-based ones (Hopper, Fetch, ...) carry the mujoco mark."""
    light = {"digail/FourRooms-v0", "digail/CircleWorld-v0", "digail/LandmarkRoute-v0", "Pendulum-v1"}
    return [pytest.param(ds_id, marks=() if dataset_env_id(ds_id) in light else pytest.mark.mujoco)
            for ds_id in shipped_dataset_ids()]


@pytest.mark.parametrize("dataset_id", _shipped_params())
def test_shipped_dataset(dataset_id: str) -> None:
    ds = load_dataset(dataset_id)
    assert ds.path == SHIPPED_ROOT / dataset_id and ds.env_id is not None
    env_id = ds.env_id
    assert len(ds.trajs) == ds.metadata["digail"]["episodes"] == ENV_SPECS[env_id].demo_episodes  # the paper's sizes
    check_matches_env(ds, env_id)
    size = sum(f.stat().st_size for f in (ds.path / "data").iterdir())
    assert size < 6_000_000, size  # "a few MB" each, as the shipped datasets promise; Walker and Fetch are ~4.8 MB
    expert = get_scripted_expert(env_id)
    if env_id in ORACLE_LABELS or expert is not None:
        assert ds.has_labels
    if env_id in ORACLE_LABELS:
        labels = np.concatenate([t.subtasks for t in ds.trajs if t.subtasks is not None])
        assert set(labels.tolist()) == ORACLE_LABELS[env_id]
    if expert is None:
        return
    # the data is what the current env and scripted expert produce (catches drift after env changes)
    env = make_env(env_id)
    fresh = rollout_episodes(env, lambda e, obs: expert(e), 3, seed=ds.metadata["digail"]["seed"])
    env.close()
    for a, b in zip(fresh, ds.trajs[:3], strict=True):
        np.testing.assert_array_equal(a.obs, b.obs)
        np.testing.assert_array_equal(a.acts, b.acts)
        np.testing.assert_array_equal(a.subtasks, b.subtasks)
        assert a.terminated == b.terminated


def test_shipped_manifest_is_current() -> None:
    manifest = json.loads((SHIPPED_ROOT / "MANIFEST.json").read_text())
    assert manifest == json.loads(json.dumps(build_manifest())), \
        "MANIFEST.json is stale: run `python -m digail.data.demos` after changing a shipped dataset"
    entries = {e["id"]: e for e in manifest["datasets"]}
    assert entries["digail/fourrooms/expert-v0"]["episodes"] == 300
    assert entries["digail/circleworld/expert-v0"]["episodes"] == 100
    for entry in entries.values():
        assert entry["command"].startswith(f"digail demos {entry['env']} --episodes {entry['episodes']} ")
    assert set(entries["digail/fourrooms/expert-v0"]["label_counts"]) == {"0", "1", "2", "3", "4"}


def test_write_dataset_refuses_shipped_layout_clash(tmp_path: Path) -> None:
    """Writing over a shipped dataset needs --force like any other folder."""
    ds = load_dataset("digail/circleworld/expert-v0")
    with pytest.raises(UserError, match="already exists"):
        write_dataset(ds.trajs[:1], ds.path, "digail/CircleWorld-v0", ds.dataset_id)
