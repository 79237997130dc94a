"""Datasets that do not say the truth about themselves: metadata naming an env the data does not fit, an env that
cannot be made here or none at all, ids that climb out of the Minari root, and K chosen from one demonstration.

Each case runs `digail.cli.main` in-process on a few short Pendulum episodes (SMOKE settings) and checks the
sentence, the exit status and that nothing was written.
"""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import pytest

from digail.cli import main
from digail.data.minari_io import load_dataset
from digail.data.minari_write import write_dataset
from digail.data.trajectory import Trajectory
from digail.errors import UserError

PENDULUM = "Pendulum-v1"


@pytest.fixture(scope="module")
def pendulum(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """Three 40-step Pendulum episodes of the shipped demonstrations, as a Minari dataset."""
    trajs = [Trajectory(obs=t.obs[:41], acts=t.acts[:40], rews=None if t.rews is None else t.rews[:40])
             for t in load_dataset("digail/pendulum/expert-v0").trajs[:3]]
    return write_dataset(trajs, tmp_path_factory.mktemp("data") / "pendulum", PENDULUM, "test/pendulum-v0")


def _with_env_id(src: Path, dst: Path, env_id: str | None) -> Path:
    """A copy of dataset `src` whose metadata names `env_id` (None: no env spec at all), its data unchanged."""
    shutil.copytree(src, dst)
    meta_file = dst / "data" / "metadata.json"
    meta = json.loads(meta_file.read_text())
    if env_id is None:
        del meta["env_spec"]
    else:
        spec = json.loads(meta["env_spec"])
        spec["id"] = env_id
        meta["env_spec"] = json.dumps(spec)
    meta_file.write_text(json.dumps(meta))
    return dst


def _cli(capsys: pytest.CaptureFixture[str], *argv: str) -> tuple[int, str, str]:
    code = main(list(argv))
    out, err = capsys.readouterr()
    return code, out, err.strip()


def _refused(code: int, err: str, *phrases: str) -> None:
    assert code == 2, err
    assert len(err.splitlines()) == 1 and err.endswith("."), err
    for phrase in phrases:
        assert phrase in err, err


def test_pretrain_refuses_data_of_another_env(tmp_path: Path, capsys: pytest.CaptureFixture[str],
                                              pendulum: Path) -> None:
    """Metadata naming CartPole over Pendulum observations: refused at pretrain, as `digail train` refuses it."""
    bad = _with_env_id(pendulum, tmp_path / "bad", "CartPole-v1")
    out = tmp_path / "vae"
    code, _, err = _cli(capsys, "pretrain", "--demos", str(bad), "--preset", "smoke", "--out", str(out))
    _refused(code, err, "observations of shape (3,)", "CartPole-v1")
    assert not out.exists()
    code, _, err_train = _cli(capsys, "train", "--demos", str(bad), "--preset", "smoke", "--method", "gail",
                              "--out", str(tmp_path / "run"))
    _refused(code, err_train, "observations of shape (3,)")


@pytest.mark.parametrize("env_id", ["NoSuchEnv-v3", None], ids=["unknown env", "no env spec"])
def test_dataset_only_path(tmp_path: Path, capsys: pytest.CaptureFixture[str], pendulum: Path,
                           env_id: str | None) -> None:
    """An env that cannot be made here (or none named): pre-training and segmentation run from the dataset's spaces
    and say what will not work; train and evaluate refuse in one sentence."""
    data = _with_env_id(pendulum, tmp_path / "data", env_id)
    vae = tmp_path / "vae"
    code, out, err = _cli(capsys, "pretrain", "--demos", str(data), "--preset", "smoke", "--out", str(vae))
    assert code == 0, err
    note = [line for line in out.splitlines() if line.startswith("note:")]
    assert len(note) == 1 and "`digail train`, `evaluate` and `run` need an environment" in note[0], out
    if env_id is not None:
        assert f"{env_id}, which cannot be made here (unknown environment id" in note[0]
    code, _, err = _cli(capsys, "segment", str(vae))
    assert code == 0, err
    assert (vae / "segmentation.json").is_file()

    code, _, err = _cli(capsys, "train", "--demos", str(data), "--vae", str(vae), "--preset", "smoke", "--out",
                        str(tmp_path / "run"))
    if env_id is not None:
        _refused(code, err, f"recorded in {env_id}, which cannot be made here", "`digail segment` work")
    else:
        _refused(code, err, "does not name its environment", "--env")
    assert not (tmp_path / "run").exists()
    code, _, err = _cli(capsys, "evaluate", str(vae), "--episodes", "1")
    _refused(code, err, env_id or "cannot tell which environment")


def test_dataset_id_stays_in_minari_root(tmp_path: Path, capsys: pytest.CaptureFixture[str],
                                         monkeypatch: pytest.MonkeyPatch, pendulum: Path) -> None:
    """`../` in an id must not reach a dataset outside `MINARI_DATASETS_PATH` (a folder path still may)."""
    root, elsewhere, cwd = tmp_path / "root", tmp_path / "elsewhere", tmp_path / "a" / "b" / "c"
    root.mkdir()
    cwd.mkdir(parents=True)
    shutil.copytree(pendulum, elsewhere / "secret")
    shutil.copytree(pendulum, root / "test" / "inside-v0")
    monkeypatch.setenv("MINARI_DATASETS_PATH", str(root))
    monkeypatch.chdir(cwd)
    assert load_dataset("test/inside-v0").path == root / "test" / "inside-v0"
    for ref in ("../elsewhere/secret", "test/../../elsewhere/secret"):
        with pytest.raises(UserError, match="leads outside the Minari root"):
            load_dataset(ref)
    out = tmp_path / "vae"
    code, _, err = _cli(capsys, "pretrain", "--demos", "../elsewhere/secret", "--preset", "smoke", "--out", str(out))
    _refused(code, err, "leads outside the Minari root", "folder path")
    assert not out.exists()
    assert load_dataset(elsewhere / "secret").env_id == PENDULUM  # the same data by its path


def test_codes_auto_needs_two_demonstrations(tmp_path: Path, capsys: pytest.CaptureFixture[str],
                                             pendulum: Path) -> None:
    one = write_dataset(load_dataset(pendulum).trajs[:1], tmp_path / "one", PENDULUM, "test/one-v0")
    out = tmp_path / "vae"
    code, _, err = _cli(capsys, "pretrain", "--demos", str(one), "--codes", "auto", "--max-codes", "3", "--preset",
                        "smoke", "--out", str(out))
    _refused(code, err, "K cannot be chosen from 1 demonstration", "--codes K")
    assert not out.exists()


def test_select_codes_refuses_one_demonstration(pendulum: Path) -> None:
    """The library call refuses too (the command checks first, before any folder is made)."""
    from digail.algos.vae_pretrain import select_codes
    from digail.preset import get_preset

    with pytest.raises(UserError, match="K cannot be chosen from 1 demonstration"):
        select_codes(load_dataset(pendulum).trajs[:1], get_preset("smoke").vae, [2, 3], progress=False)


def test_a_file_is_not_a_dataset(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """An .npz given where a dataset is read points to `digail import` (not to recording demonstrations)."""
    file = tmp_path / "mine.npz"
    file.write_bytes(b"")
    code, _, err = _cli(capsys, "pretrain", "--demos", str(file), "--out", str(tmp_path / "vae"))
    _refused(code, err, "is a file, not a Minari dataset folder", f"digail import {file}")
    assert not (tmp_path / "vae").exists()
