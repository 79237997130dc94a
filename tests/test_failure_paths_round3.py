"""Failure paths, third round: nothing of the user's is deleted or written outside its place, and every bad file
gets one sentence.

`--force` replaces only a folder digail made (its `.digail` marker, or a run's or dataset's record from before the
marker), never the current directory, a folder above it, the home folder or a filesystem root; a damaged or
oversized file, a tampered checkpoint, a lock file in the way or a path that is not UTF-8 is one sentence with exit
status 2 and nothing written; a killed sweep stage leaves no temporary folder for long; a refused `digail run`
leaves no folder that blocks the corrected command.
"""

from __future__ import annotations

import io
import shutil
import sys
import types
import zipfile
from pathlib import Path

import h5py
import numpy as np
import pytest
import torch

from digail.cli import main
from digail.errors import UserError
from digail.fsio import MARKER, check_replaceable, digail_made, run_dir_lock

CW = "digail/CircleWorld-v0"
CW_DEMOS = "digail/circleworld/expert-v0"
REPO = Path(__file__).resolve().parents[1]


def one_line_error(capsys: pytest.CaptureFixture[str], code: int, *phrases: str) -> str:
    err = capsys.readouterr().err
    assert code == 2, err
    lines = [ln for ln in err.splitlines() if ln.strip() and "is deprecated" not in ln]
    assert len(lines) == 1 and ": error: " in lines[0], err
    assert "Traceback" not in err
    for phrase in phrases:
        assert phrase in lines[0], lines[0]
    return lines[0]


def tree(path: Path) -> dict[str, bytes]:
    return {str(p.relative_to(path)): p.read_bytes() for p in sorted(path.rglob("*")) if p.is_file()}


def users_folder(path: Path) -> Path:
    (path / "notes").mkdir(parents=True)
    (path / "thesis.tex").write_text("a user's file\n")
    (path / "notes" / "todo.txt").write_text("more of them\n")
    return path


# ------------------------------------------------------------------------------------------------ --force
FORCE_COMMANDS = {
    "train": ["train", "--method", "gail", "--demos", CW_DEMOS, "--preset", "smoke", "--out", "{out}", "--force"],
    "run": ["run", CW, "--preset", "smoke", "--out", "{out}", "--force"],
    "pretrain": ["pretrain", "--demos", CW_DEMOS, "--preset", "smoke", "--out", "{out}", "--force"],
    "demos": ["demos", "digail/FourRooms-v0", "--episodes", "2", "--out", "{out}", "--force"],
    "import": ["import", "{npz}", "--out", "{out}", "--force"],
}


@pytest.fixture
def npz(tmp_path: Path) -> Path:
    rng = np.random.default_rng(0)
    path = tmp_path / "demos.npz"
    np.savez(path, observations=rng.normal(size=(20, 3)).astype(np.float32),
             actions=rng.normal(size=(20, 1)).astype(np.float32), episode_ends=np.array([10, 20]))
    return path


def _argv(name: str, out: Path | str, npz: Path) -> list[str]:
    return [a.replace("{out}", str(out)).replace("{npz}", str(npz)) for a in FORCE_COMMANDS[name]]


@pytest.mark.parametrize("name", list(FORCE_COMMANDS))
def test_force_refuses_a_folder_digail_did_not_make(name, tmp_path, npz, capsys):
    victim = users_folder(tmp_path / "mine")
    before = tree(victim)
    code = main(_argv(name, victim, npz))
    one_line_error(capsys, code, "is not a folder digail made", "--force replaces only those")
    assert tree(victim) == before and not (victim / MARKER).exists()


@pytest.mark.parametrize("name", ["train", "pretrain", "import"])
def test_force_never_deletes_the_current_directory_or_a_folder_above_it(name, tmp_path, npz, capsys, monkeypatch):
    inner = tmp_path / "a" / "inner"
    inner.mkdir(parents=True)
    (inner / "work.txt").write_text("unsaved\n")
    (inner / MARKER).write_text("even one digail made\n")  # the marker does not make the cwd replaceable
    (tmp_path / "a" / MARKER).write_text("nor a folder above it\n")
    before = tree(tmp_path / "a")
    monkeypatch.chdir(inner)
    for out, what in ((".", "the current directory"), ("..", "a folder holding the current directory")):
        code = main(_argv(name, out, npz))
        one_line_error(capsys, code, f"--force would delete {out}, {what}")
    assert tree(tmp_path / "a") == before


def test_force_never_deletes_the_home_folder_or_a_filesystem_root(tmp_path, monkeypatch):
    home = tmp_path / "home"
    home.mkdir()
    (home / MARKER).write_text("\n")
    monkeypatch.setenv("HOME", str(home))
    monkeypatch.chdir(tmp_path)
    with pytest.raises(UserError, match="the home folder"):
        check_replaceable(home)
    with pytest.raises(UserError, match="--force would delete /"):
        check_replaceable(Path("/"))


def test_force_refuses_a_file_and_a_link_to_a_users_folder(tmp_path, npz, capsys):
    file = tmp_path / "out"
    file.write_text("a user's file\n")
    one_line_error(capsys, main(_argv("import", file, npz)), "is a file, and --force replaces only a folder")
    assert file.read_text() == "a user's file\n"
    victim = users_folder(tmp_path / "mine")
    link = tmp_path / "link"
    link.symlink_to(victim)
    one_line_error(capsys, main(_argv("import", link, npz)), "is not a folder digail made")
    assert link.is_symlink() and tree(victim) == tree(users_folder(tmp_path / "again"))


def test_force_replaces_what_digail_made_and_marks_every_new_folder(tmp_path, npz, capsys):
    out = tmp_path / "data"
    assert main(_argv("import", out, npz)) == 0
    assert (out / MARKER).is_file()
    (out / "extra.txt").write_text("added later\n")
    assert main(_argv("import", out, npz)) == 0  # the marker says digail made it: replaced whole
    assert (out / MARKER).is_file() and not (out / "extra.txt").exists()
    empty = tmp_path / "empty"
    empty.mkdir()
    assert main(_argv("import", empty, npz)) == 0  # an empty folder loses nothing
    capsys.readouterr()


def test_folders_from_before_the_marker_count_as_digails():
    """The committed run folders and the shipped datasets carry no marker; their records make them digail's."""
    runs = sorted((REPO / "benchmarks" / "results" / "runs").iterdir())
    assert runs and all(digail_made(r) for r in runs if r.is_dir())
    datasets = sorted((REPO / "src" / "digail" / "datasets" / "digail").glob("*/expert-v0"))
    assert datasets and all(digail_made(d) for d in datasets)


def test_a_json_file_alone_does_not_make_a_folder_digails(tmp_path):
    folder = users_folder(tmp_path / "mine")
    (folder / "config.json").write_text('{"lr": 0.1}\n')  # some other tool's config
    assert not digail_made(folder)
    (folder / "config.json").write_text("[1, 2]\n")
    assert not digail_made(folder)


# ------------------------------------------------------------------------------------------------ bad files
def _npz_with_header(path: Path, shape: tuple[int, ...]) -> None:
    """observations declared as `shape` float32 with a few bytes of data; the other arrays fine."""
    head = io.BytesIO()
    np.lib.format.write_array_header_1_0(head, {"descr": "<f4", "fortran_order": False, "shape": shape})
    with zipfile.ZipFile(path, "w") as z:
        z.writestr("observations.npy", head.getvalue() + b"\0" * 64)
        for key, arr in (("actions", np.zeros((20, 1), np.float32)), ("episode_ends", np.array([10, 20]))):
            buf = io.BytesIO()
            np.save(buf, arr)
            z.writestr(f"{key}.npy", buf.getvalue())


def _good() -> dict[str, np.ndarray]:
    rng = np.random.default_rng(1)
    return {"observations": rng.normal(size=(20, 3)).astype(np.float32),
            "actions": rng.normal(size=(20, 1)).astype(np.float32), "episode_ends": np.array([10, 20])}


def _truncated(path: Path) -> None:
    np.savez(path, **_good())
    data = path.read_bytes()
    path.write_bytes(data[: len(data) // 2])


def _truncated_member(path: Path) -> None:
    """A compressed member cut inside its data, the zip's directory intact."""
    np.savez_compressed(path, **_good())
    data = bytearray(path.read_bytes())
    data[60:80] = bytes(20)
    path.write_bytes(bytes(data))


def _h5(path: Path, **arrays: object) -> None:
    with h5py.File(path, "w") as f:
        for key, value in arrays.items():
            if isinstance(value, tuple):  # (shape, chunks): declared, never written
                f.create_dataset(key, shape=value[0], dtype="f4", chunks=value[1])
            else:
                f[key] = value


BAD_FILES = {
    "truncated.npz": (_truncated, "as an .npz file"),
    "member_damaged.npz": (_truncated_member, "the file is damaged"),
    "huge_header.npz": (lambda p: _npz_with_header(p, (10**12, 3)), "declares 'observations' as a (1000000000000, 3)"),
    "complex.npz": (lambda p: np.savez(p, **{**_good(), "observations": _good()["observations"] + 1j}),
                    "complex values in 'observations'"),
    "beyond_float32.npz": (lambda p: np.savez(p, **{**_good(), "observations": _good()["observations"]
                                                    .astype(np.float64) * 1e300}), "beyond float32's range"),
    "terminals_2d.hdf5": (lambda p: _h5(p, observations=np.zeros((20, 3), np.float32),
                                        actions=np.zeros((20, 1), np.float32), terminals=np.zeros((20, 2), bool)),
                          "'terminals' of shape (20, 2)"),
    "huge_chunked.hdf5": (lambda p: _h5(p, observations=((10**12, 3), (1024, 3)),
                                        actions=np.zeros((20, 1), np.float32), terminals=np.zeros(20, bool)),
                          "of memory available"),
    "huge_contiguous.hdf5": (lambda p: _h5(p, observations=((10**11, 3), None),
                                           actions=np.zeros((20, 1), np.float32), terminals=np.zeros(20, bool)),
                             "the file is damaged or cut short"),
}


@pytest.mark.parametrize("name", list(BAD_FILES))
def test_a_bad_file_is_one_sentence_and_writes_nothing(name, tmp_path, capsys):
    make, phrase = BAD_FILES[name]
    source = tmp_path / name
    make(source)
    out = tmp_path / "out"
    line = one_line_error(capsys, main(["import", str(source), "--out", str(out)]), phrase)
    assert "pickled" not in line and not out.exists()
    assert sorted(p.name for p in tmp_path.iterdir()) == [name]


def test_demos_subsample_longer_than_every_episode_is_refused(capsys, tmp_path):
    from digail.data.minari_io import load_dataset
    from digail.data.subset import select_demos

    trajs = list(load_dataset(CW_DEMOS).trajs)[:2]
    longest = max(len(t) for t in trajs)
    with pytest.raises(UserError, match=f"the longest has {longest} transitions"):
        select_demos(trajs, every=longest)
    assert all(len(t) > 1 for t in select_demos(trajs, every=longest // 2))
    out = tmp_path / "vae"
    code = main(["pretrain", "--demos", CW_DEMOS, "--preset", "smoke", "--demos-subsample", "100000", "--out",
                 str(out)])
    one_line_error(capsys, code, "--demos-subsample 100000 is at least as long as every demonstration")
    assert not out.exists()


def test_a_replay_buffer_larger_than_memory_is_refused(tmp_path, capsys):
    out = tmp_path / "run"
    code = main(["train", "--method", "gail", "--demos", CW_DEMOS, "--preset", "smoke", "--train.learner", "sac",
                 "--train.sac.buffer-size", "1000000000000", "--out", str(out)])
    one_line_error(capsys, code, "--train.sac.buffer-size 1000000000000 needs", "of memory is available")
    assert not out.exists()


def _filled_buffer() -> tuple[object, dict[str, object]]:
    from digail.algos.replay import ReplayBuffer

    buf = ReplayBuffer(8, obs_dim=2, act_dim=1, codes=3)
    rng = np.random.default_rng(0)
    n = 5
    buf.add(rng.normal(size=(n, 2)), rng.integers(3, size=n), rng.normal(size=(n, 1)), rng.normal(size=(n, 2)),
            rng.integers(3, size=n), np.zeros(n, bool), rng.normal(size=n), rng.normal(size=n))
    return buf, buf.state_dict()


@pytest.mark.parametrize(("change", "phrase"), [
    ({"pos": 2}, "records 5 transitions and write position 2"),
    ({"size": 4}, "records 4 transitions and write position 5"),
    ({"pos": -1}, "write position -1"),
    ({"size": 9, "pos": 1}, "records 9 transitions"),
    ({"obs": "nan"}, "holds NaN or inf values in 'obs'"),
    ({"bonus": "inf"}, "holds NaN or inf values in 'bonus'"),
    ({"codes": -1}, "holds codes this model does not have"),
])
def test_a_tampered_replay_buffer_is_refused(change, phrase):
    from digail.algos.replay import ReplayBuffer

    _, state = _filled_buffer()
    state = dict(state)
    for key, value in change.items():
        if value in ("nan", "inf"):
            arr = state[key].clone()
            arr.view(-1)[0] = float(value)
            state[key] = arr
        elif key == "codes":
            arr = state[key].clone()
            arr[0] = value
            state[key] = arr
        else:
            state[key] = value
    with pytest.raises(UserError, match=phrase.replace("(", r"\(")):
        ReplayBuffer(8, obs_dim=2, act_dim=1, codes=3).load_state_dict(state)


def test_an_intact_replay_buffer_still_loads():
    from digail.algos.replay import ReplayBuffer

    buf, state = _filled_buffer()
    again = ReplayBuffer(8, obs_dim=2, act_dim=1, codes=3)
    again.load_state_dict(state)
    assert (again.pos, again.size) == (buf.pos, buf.size)
    assert torch.equal(again.rows, buf.rows)


def test_a_lock_file_that_is_a_folder_is_one_sentence(tmp_path, capsys):
    run = tmp_path / "run"
    (run / ".digail.lock").mkdir(parents=True)
    with pytest.raises(UserError, match="is a folder, not digail's lock file"), run_dir_lock(run):
        pass
    one_line_error(capsys, main(["segment", str(run)]), "is a folder, not digail's lock file")


@pytest.mark.parametrize("argv", [
    ["train", "--method", "gail", "--demos", CW_DEMOS, "--preset", "smoke", "--out", "OUT"],
    ["pretrain", "--demos", "DEMOS", "--preset", "smoke"],
    ["report", "OUT"],
    ["import", "DEMOS", "--out", "OUT"],
])
def test_a_path_that_is_not_utf8_is_refused_up_front(argv, tmp_path, capsys, monkeypatch):
    bad = "r\udcffn"  # the byte 0xff in a file name, as Python shows it
    monkeypatch.chdir(tmp_path)
    words = [a.replace("OUT", bad).replace("DEMOS", bad + ".npz") for a in argv]
    one_line_error(capsys, main(words), "is not valid UTF-8", "r\\xffn")
    assert list(tmp_path.iterdir()) == []


# ------------------------------------------------------------------------------------------------ left behind
def test_a_refused_run_leaves_no_folder_behind(tmp_path, npz, capsys):
    out = tmp_path / "run"
    code = main(["run", CW, "--preset", "smoke", "--demos-episodes", "100000", "--out", str(out)])
    one_line_error(capsys, code, "--demos-episodes 100000 asks for more episodes")
    code = main(["run", "Pendulum-v1", "--demos", str(npz), "--demos-episodes", "50", "--out", str(out)])
    one_line_error(capsys, code, "--demos-episodes 50 asks for more episodes")
    assert not out.exists()
    assert sorted(p.name for p in tmp_path.iterdir()) == ["demos.npz"]


def test_a_refused_subset_after_recording_removes_the_folder(tmp_path, monkeypatch, capsys):
    """Demonstrations recorded into the run folder, then found too few: the folder goes, so that the corrected
    command is not refused as "already exists"."""
    import digail.commands.run as run_mod

    def refuse(*_: object, **__: object) -> None:
        (tmp_path / "run" / "demos").mkdir()  # what recording them would have left
        raise run_mod._SubsetRefused("--demos-episodes 9 asks for more episodes than the dataset's 2; pass at most "
                                     "that many.")

    monkeypatch.setattr(run_mod, "_run_stages", refuse)
    code = main(["run", CW, "--preset", "smoke", "--out", str(tmp_path / "run")])
    one_line_error(capsys, code, "asks for more episodes")
    assert not (tmp_path / "run").exists()


def _stale(sweep: Path) -> list[Path]:
    return sorted(sweep.rglob(".vae_s0.*"))


def test_a_resumed_sweep_stage_removes_what_a_killed_attempt_left(tmp_path):
    from digail.sweep.engine import run_job
    from digail.sweep.plan import Job, Stage

    sweep = tmp_path / "sweep"
    left = sweep / "env" / ".vae_s0.tmp-abc123"
    (left / "figures").mkdir(parents=True)
    (left / "losses.csv").write_text("epoch,loss\n")
    (sweep / "env" / ".vae_s0.old-xyz").mkdir()
    (sweep / "env" / ".other.tmp-1").mkdir()  # another folder's: not this stage's to remove
    job = Job(id="env/pretrain_s0", kind="vae", env=CW, method="pretrain", seed=0, run="env/vae_s0",
              stages=(Stage("pretrain", ("pretrain", "--help"), run="env/vae_s0"),))
    from digail.sweep.engine import job_to_dict

    run_job(job_to_dict(job), str(sweep))
    assert _stale(sweep) == [] and (sweep / "env" / ".other.tmp-1").is_dir()


def test_an_interrupted_sweep_removes_its_killed_stages_temporaries(tmp_path, monkeypatch):
    from digail.sweep import engine
    from digail.sweep.plan import Job, Stage

    sweep = tmp_path / "sweep"
    job = Job(id="env/pretrain_s0", kind="vae", env=CW, method="pretrain", seed=0, run="env/vae_s0",
              stages=(Stage("pretrain", ("pretrain",), run="env/vae_s0"),))
    cancelled = []

    class Remote:
        def options(self, **_: object) -> Remote:
            return self

        def remote(self, *_: object) -> str:
            # the stage starts writing its VAE atomically, then the user presses Ctrl-C
            (sweep / "env" / ".vae_s0.tmp-k1ll3d").mkdir(parents=True)
            return "ref"

    def wait(*_: object, **__: object) -> None:
        raise KeyboardInterrupt

    fake = types.SimpleNamespace(remote=lambda fn: Remote(), cluster_resources=lambda: {"CPU": 2.0}, wait=wait,
                                 cancel=lambda ref, force: cancelled.append(ref), is_initialized=lambda: False)
    monkeypatch.setitem(sys.modules, "ray", fake)
    with pytest.raises(KeyboardInterrupt):
        engine.execute([job], sweep, shared_fs=True, log=lambda _: None)
    assert cancelled == ["ref"] and _stale(sweep) == []


def test_sweep_folders_carry_the_marker(tmp_path):
    from digail.sweep import Grid, SweepSpec, plan, save_plan

    spec = SweepSpec(grids=(Grid(envs=(CW,), methods=("vae",), preset="smoke"),))
    save_plan(tmp_path / "sweep", spec, plan(spec))
    assert (tmp_path / "sweep" / MARKER).is_file() and digail_made(tmp_path / "sweep")
    shutil.rmtree(tmp_path / "sweep")


@pytest.mark.parametrize("spec_file", sorted((REPO / "benchmarks" / "sweeps").glob("*.toml")), ids=lambda p: p.name)
def test_every_shipped_sweep_spec_passes_the_checks_before_ray(spec_file):
    """The allow-list keeps every override the published sweeps use; `demos.*` keys are checked against both the
    VAE's and the training's command (they once crashed the check with a KeyError)."""
    from digail.commands.sweep import check_spec
    from digail.sweep.plan import plan
    from digail.sweep.spec import build_spec

    spec = build_spec(spec_file=spec_file)
    check_spec(spec, plan(spec) if spec.search is None else [])
