"""Every way a command line can go wrong gives one sentence on stderr, exit status 2 and an untouched output.

One table: each case names the argv (with placeholders for the fixture's folders), an optional setup that breaks
something first, a phrase of the expected message, and the path that must come out unchanged. Runs in-process
(`digail.cli.main`); the only training is the module fixture's two SMOKE iterations on Four Rooms.
"""

from __future__ import annotations

import errno
import html
import html.parser
import json
import os
import pickle
import resource
import shutil
import signal
import subprocess
import sys
import tempfile
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import pytest

from digail.cli import main

ENV = "digail/FourRooms-v0"


@pytest.fixture(scope="module")
def runs(tmp_path_factory):
    """A tiny dataset, a VAE folder and a trained folder (Four Rooms, SMOKE)."""
    root = tmp_path_factory.mktemp("errors")
    demos, vae, run = root / "demos", root / "vae", root / "run"
    assert main(["demos", ENV, "--episodes", "6", "--out", str(demos)]) == 0
    assert main(["pretrain", "--demos", str(demos), "--preset", "smoke", "--out", str(vae)]) == 0
    assert main(["train", "--demos", str(demos), "--vae", str(vae), "--preset", "smoke", "--out", str(run)]) == 0
    return root


@dataclass
class Case:
    argv: list[str]
    """the command line; {demos}, {vae}, {run}, {tmp} and {file} are filled in"""
    phrase: str
    """a piece of the expected one-line message"""
    watch: str = "{tmp}/out"
    """the output location that must be unchanged afterwards (absent stays absent)"""
    setup: Callable[[Path, pytest.MonkeyPatch], None] | None = None
    """breaks something first (in the test's own copy of the run folder)"""


def _write(name: str, data: bytes | str) -> Callable[[Path, pytest.MonkeyPatch], None]:
    def setup(tmp: Path, _: pytest.MonkeyPatch) -> None:
        path = tmp / "run" / name
        path.write_bytes(data if isinstance(data, bytes) else data.encode())
    return setup


def _forget_demos(tmp: Path, _: pytest.MonkeyPatch) -> None:
    path = tmp / "run" / "config.json"
    config = json.loads(path.read_text())
    config.pop("demos", None)
    path.write_text(json.dumps(config))


def _torch_bytes(obj: object) -> bytes:
    import io

    import torch

    buf = io.BytesIO()
    torch.save(obj, buf)
    return buf.getvalue()


class _Hostile:
    def __reduce__(self):  # noqa: ANN204  (runs `touch` when unpickled with weights_only=False)
        return os.system, (f"touch {tempfile.gettempdir()}/digail-hostile-pickle-ran",)


def _unwritable(tmp: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """A read-only run folder: as root chmod does not stop writes, so the probe's mkstemp fails as on a read-only
    mount (os.access would say yes to root)."""
    real = tempfile.mkstemp

    def mkstemp(*args, **kwargs):  # noqa: ANN002, ANN003, ANN202
        if Path(kwargs.get("dir", "")).resolve() == (tmp / "run").resolve():
            raise OSError(errno.EROFS, "Read-only file system")
        return real(*args, **kwargs)

    monkeypatch.setattr(tempfile, "mkstemp", mkstemp)


def _full_disk(tmp: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr(shutil, "disk_usage", lambda _: shutil._ntuple_diskusage(100, 100, 0))  # type: ignore


def _disk_fills_up(tmp: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """The disk fills up after the checks, while the results are written."""
    import digail.fsio

    def write_json(path, obj):  # noqa: ANN001, ANN202
        raise OSError(errno.ENOSPC, "No space left on device", str(path))

    monkeypatch.setattr(digail.fsio, "write_json", write_json)


def _file_too_large(tmp: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """A file-size limit (`ulimit -f`) is reached while the results are written."""
    import digail.fsio

    def write_json(path, obj):  # noqa: ANN001, ANN202
        raise OSError(errno.EFBIG, "File too large")

    monkeypatch.setattr(digail.fsio, "write_json", write_json)


def _ffmpeg_stops(tmp: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """ffmpeg exits while the frames are piped to it (as on a read-only mount it was not probed on)."""
    import imageio.v2 as imageio

    real = imageio.mimsave

    def mimsave(uri, *args, **kwargs):  # noqa: ANN001, ANN002, ANN003, ANN202
        if str(uri).endswith(".mp4"):
            Path(uri).write_bytes(b"half a video")
            raise BrokenPipeError(32, "Broken pipe")
        return real(uri, *args, **kwargs)

    monkeypatch.setattr(imageio, "mimsave", mimsave)


def _mkdir(name: str) -> Callable[[Path, pytest.MonkeyPatch], None]:
    def setup(tmp: Path, _: pytest.MonkeyPatch) -> None:
        (tmp / name).mkdir()
    return setup


TRAIN = ["train", "--demos", "{demos}", "--vae", "{vae}", "--preset", "smoke", "--out", "{tmp}/out"]
RUN = "{tmp}/run"

CASES: dict[str, Case] = {
    # 1. resume
    "resume a VAE folder": Case(["train", "--resume", "{vae}"], "VAE run folder", watch="{vae}"),
    "resume a missing folder": Case(["train", "--resume", "{tmp}/nope"], "does not exist", watch="{tmp}/nope"),
    "resume a folder without config": Case(["train", "--resume", "{tmp}"], "not a training run folder",
                                           watch="{tmp}"),
    "run --resume a train folder": Case(["run", "--resume", RUN], "digail train --resume", watch=RUN),
    "re-run an existing folder": Case([*TRAIN[:-1], RUN], "--resume", watch=RUN),
    # 2. unwritable outputs
    "--out on a read-only mount": Case([*TRAIN[:-1], "/proc/digail-out"], "cannot write",
                                       watch="/proc/digail-out"),
    "--out below a file": Case([*TRAIN[:-1], "{file}/out"], "is a file", watch="{file}"),
    "evaluate a read-only run": Case(["evaluate", RUN, "--episodes", "2"], "cannot write", watch=RUN,
                                     setup=_unwritable),
    "compose in a read-only run": Case(["compose", RUN, "--schedule", "0:5", "--episodes", "2"], "cannot write",
                                       watch=RUN, setup=_unwritable),
    "segment a read-only run": Case(["segment", RUN], "cannot write", watch=RUN, setup=_unwritable),
    "resume a read-only run": Case(["train", "--resume", RUN], "cannot write", watch=RUN, setup=_unwritable),
    "evaluate on a full disk": Case(["evaluate", RUN, "--episodes", "2"], "MiB free", watch=RUN,
                                    setup=_full_disk),
    "disk fills up while writing": Case(["evaluate", RUN, "--episodes", "2"], "no space left", watch=RUN,
                                        setup=_disk_fills_up),
    "file-size limit reached while writing": Case(["evaluate", RUN, "--episodes", "2"], "file too large",
                                                  watch=RUN, setup=_file_too_large),
    # 3. numbers
    "evaluate --episodes 0": Case(["evaluate", RUN, "--episodes", "0"], "--episodes must be at least 1",
                                  watch=RUN),
    "compose --episodes -1": Case(["compose", RUN, "--episodes", "-1"], "--episodes must be at least 1",
                                  watch=RUN),
    "run --episodes 0": Case(["run", ENV, "--episodes", "0", "--out", "{tmp}/out"], "--episodes"),
    "demos --episodes 0": Case(["demos", ENV, "--episodes", "0", "--out", "{tmp}/out"], "--episodes"),
    "num-envs 0": Case([*TRAIN, "--train.ppo.num-envs", "0"], "--train.ppo.num-envs must be at least 1"),
    "minibatch 0": Case([*TRAIN, "--train.ppo.minibatch-size", "0"], "--train.ppo.minibatch-size"),
    "minibatch > batch": Case([*TRAIN, "--train.ppo.minibatch-size", "4096"], "must not exceed"),
    "checkpoint-every 0": Case([*TRAIN, "--train.checkpoint-every", "0"], "--train.checkpoint-every"),
    "negative lr": Case([*TRAIN, "--train.ppo.lr", "-0.1"], "--train.ppo.lr"),
    "negative disc lr": Case([*TRAIN, "--train.imitation.disc-lr", "-1e-3"], "--train.imitation.disc-lr"),
    "negative VAE lr": Case(["pretrain", "--demos", "{demos}", "--vae.lr", "-1", "--out", "{tmp}/out"],
                            "--vae.lr"),
    "seed -1": Case([*TRAIN, "--seed", "-1"], "--seed must be between 0 and"),
    "seed 2**32": Case(["run", ENV, "--seed", str(2**32), "--out", "{tmp}/out"], "--seed"),
    "seed of 20 digits": Case(["evaluate", RUN, "--seed", "9" * 20], "--seed", watch=RUN),
    # 4. schedules
    "schedule of 3e9 steps": Case(["compose", RUN, "--schedule", "0:3000000000"], "longer than an episode",
                                  watch=RUN),
    "schedule of 20 digits": Case(["compose", RUN, "--schedule", "1:" + "9" * 20], "longer than an episode",
                                  watch=RUN),
    "schedule past the time limit": Case(["compose", RUN, "--schedule", "0:40,1:40"], "80 steps", watch=RUN),
    "schedule unreadable": Case(["compose", RUN, "--schedule", "banana"], "code:steps", watch=RUN),
    "schedule unknown code": Case(["compose", RUN, "--schedule", "7:10"], "codes", watch=RUN),
    "schedule zero steps": Case(["compose", RUN, "--schedule", "0:0"], "at least 1", watch=RUN),
    "order and schedule both": Case(["compose", RUN, "--order", "1,0", "--schedule", "1:5"], "pass one of them",
                                    watch=RUN),
    "order empty": Case(["compose", RUN, "--order", ""], "the order is empty", watch=RUN),
    "order unreadable": Case(["compose", RUN, "--order", "first,second"], "code numbers", watch=RUN),
    "order unknown code": Case(["compose", RUN, "--order", "0,9"], "the policy has", watch=RUN),
    "order repeats a code": Case(["compose", RUN, "--order", "1,1"], "twice in a row", watch=RUN),
    "order, no demonstrations recorded": Case(["compose", RUN, "--order", "1,0"], "pass --demos", watch=RUN,
                                              setup=_forget_demos),
    "order --hold 0": Case(["compose", RUN, "--order", "1,0", "--hold", "0"], "--hold must be at least 1",
                           watch=RUN),
    # 5. broken files
    "corrupt checkpoint.pt": Case(["train", "--resume", RUN], "corrupt", watch=RUN,
                                  setup=_write("checkpoint.pt", b"PK\x03\x04 truncated")),
    "hostile checkpoint.pt": Case(["train", "--resume", RUN], "corrupt", watch=RUN,
                                  setup=_write("checkpoint.pt", pickle.dumps(_Hostile()))),
    "foreign checkpoint.pt": Case(["train", "--resume", RUN], "incomplete", watch=RUN,
                                  setup=_write("checkpoint.pt", _torch_bytes({"version": 2, "iteration": 1}))),
    "text in model.pt": Case(["evaluate", RUN], "corrupt", watch=RUN, setup=_write("model.pt", "hello\n")),
    "hostile model.pt": Case(["evaluate", RUN], "corrupt", watch=RUN,
                             setup=_write("model.pt", pickle.dumps(_Hostile()))),
    "invalid config.json (segment)": Case(["segment", RUN], "not valid JSON", watch=RUN,
                                          setup=_write("config.json", "{not json")),
    "invalid config.json (resume)": Case(["train", "--resume", RUN], "not valid JSON", watch=RUN,
                                         setup=_write("config.json", "[1, 2")),
    "config.json not an object": Case(["train", "--resume", RUN], "JSON object", watch=RUN,
                                      setup=_write("config.json", "[1, 2]")),
    # 7. parse errors
    "--seed abc": Case(["evaluate", RUN, "--seed", "abc"], "--seed expects an integer, got 'abc'", watch=RUN),
    "--train.ppo.lr x": Case([*TRAIN, "--train.ppo.lr", "x"], "--train.ppo.lr expects a number"),
    "missing --demos (pretrain)": Case(["pretrain", "--out", "{tmp}/out"], "--demos is missing"),
    "missing --demos (train)": Case(["train", "--out", "{tmp}/out"], "--demos is missing"),
    "missing RUN": Case(["evaluate"], "RUN is missing"),
    "bad choice": Case([*TRAIN, "--method", "bc"], "--method must be one of digail, gail"),
    "unknown flag": Case(["evaluate", RUN, "--epsiodes", "3"], "unknown option"),
    "flag without value": Case(["evaluate", RUN, "--seed"], "--seed expects an integer"),
    # 7. videos
    "video --max-steps -1": Case(["video", RUN, "--max-steps", "-1"], "--max-steps must be at least 1", watch=RUN),
    "video --max-steps 0": Case(["video", RUN, "--max-steps", "0"], "--max-steps must be at least 1", watch=RUN),
    "video --seed -5": Case(["video", RUN, "--seed", "-5"], "--seed must be between 0 and", watch=RUN),
    "video --name ../../x": Case(["video", RUN, "--max-steps", "3", "--name", "../../x"], "plain file name",
                                 watch="{tmp}"),
    "video of a read-only run": Case(["video", RUN, "--max-steps", "3"], "cannot write", watch=RUN,
                                     setup=_unwritable),
    "ffmpeg stops while writing": Case(["video", RUN, "--max-steps", "3"], "ffmpeg could not write", watch=RUN,
                                       setup=_ffmpeg_stops),
    # 8. reports
    "report an empty folder": Case(["report", "{tmp}/empty"], "not a run folder", watch="{tmp}/empty",
                                   setup=_mkdir("empty")),
    "report a folder that is not a run": Case(["report", "{tmp}"], "not a run folder", watch="{tmp}"),
    "report --out a folder": Case(["report", RUN, "--no-figures", "--out", "{tmp}/pages"], "is a folder",
                                  watch="{tmp}", setup=_mkdir("pages")),
    "compare --out a folder": Case(["report", "--compare", RUN, "--out", "{tmp}/pages"], "is a folder",
                                   watch="{tmp}", setup=_mkdir("pages")),
    # already handled before this issue
    "unknown command": Case(["trian"], "unknown command"),
    "unknown env": Case(["run", "NoSuchEnv-v9", "--out", "{tmp}/out"], "NoSuchEnv-v9"),
    "unknown preset": Case([*TRAIN, "--preset", "huge"], "unknown preset"),
    "missing dataset": Case(["train", "--demos", "{tmp}/nodata", "--vae", "{vae}", "--out", "{tmp}/out"],
                            "no Minari dataset"),
    "digail without a VAE": Case(["train", "--demos", "{demos}", "--preset", "smoke", "--out", "{tmp}/out"],
                                 "--vae"),
    "dataset of another env": Case(["train", "--demos", "digail/circleworld/expert-v0", "--vae", "{vae}",
                                    "--preset", "smoke", "--out", "{tmp}/out"], "digail/FourRooms-v0"),
}


def _snapshot(path: Path) -> list[tuple[str, int, int]] | None:
    if not path.exists():
        return None
    if path.is_file():
        st = path.stat()
        return [(path.name, st.st_size, st.st_mtime_ns)]
    out = []
    for p in sorted(path.rglob("*")):
        st = p.stat()
        out.append((str(p.relative_to(path)), st.st_size if p.is_file() else 0, st.st_mtime_ns))
    return out


@pytest.mark.parametrize("name", list(CASES))
def test_bad_input_is_one_sentence_exit_2_and_nothing_written(name, runs, tmp_path, monkeypatch, capsys):
    case = CASES[name]
    shutil.copytree(runs / "run", tmp_path / "run")
    (tmp_path / "afile").write_text("not a folder\n")
    fill = {"demos": str(runs / "demos"), "vae": str(runs / "vae"), "tmp": str(tmp_path),
            "file": str(tmp_path / "afile")}
    argv = [a.format(**fill) for a in case.argv]
    watch = Path(case.watch.format(**fill))
    marker = Path(tempfile.gettempdir()) / "digail-hostile-pickle-ran"
    marker.unlink(missing_ok=True)
    if case.setup is not None:
        case.setup(tmp_path, monkeypatch)
    before = _snapshot(watch)
    capsys.readouterr()

    assert main(argv) == 2, name
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1, err
    assert err.startswith("digail"), err
    assert case.phrase in err, err
    assert "weights_only" not in err and "Traceback" not in err, err
    assert _snapshot(watch) == before, f"{watch} changed"
    assert not list(tmp_path.glob(".*.tmp-*")) and not list(watch.parent.glob(".*.tmp-*"))
    assert not marker.exists(), "a hostile pickle ran"


def test_force_refuses_a_file_and_empties_a_folder(runs, tmp_path, capsys):
    """--out FILE --force is refused (a file is not a folder digail made); --force empties an old run folder
    before the new run, and the new folder carries the marker that lets a later --force replace it."""
    out = tmp_path / "out"
    out.write_text("an old file\n")
    assert main(["pretrain", "--demos", str(runs / "demos"), "--preset", "smoke", "--out", str(out), "--force"]) == 2
    assert "is a file, and --force replaces only a folder digail made" in capsys.readouterr().err
    assert out.read_text() == "an old file\n"
    out.unlink()
    assert main(["pretrain", "--demos", str(runs / "demos"), "--preset", "smoke", "--out", str(out), "--force"]) == 0
    assert (out / "model.pt").is_file() and (out / ".digail").is_file()
    assert sorted(p.name for p in tmp_path.iterdir()) == ["out"], "an orphan was left beside the output"

    old = tmp_path / "old"
    shutil.copytree(runs / "run", old)
    (old / "eval.json").write_text("{}\n")
    (old / "segmentation.json").write_text("{}\n")
    assert main(["train", "--demos", str(runs / "demos"), "--vae", str(runs / "vae"), "--preset", "smoke",
                 "--out", str(old), "--force"]) == 0
    assert not (old / "eval.json").exists() and not (old / "segmentation.json").exists()
    assert (old / "model.pt").is_file()

    # the same permissions whichever command made the folder (atomic pretrain vs in-place train vs mkdir)
    plain = tmp_path / "plain"
    plain.mkdir()
    modes = {p.name: p.stat().st_mode & 0o777 for p in (out, old, plain, runs / "vae", runs / "demos")}
    assert len(set(modes.values())) == 1, modes
    files = {p.name: p.stat().st_mode & 0o777 for p in (out / "model.pt", old / "config.json", old / "model.pt")}
    assert len(set(files.values())) == 1, files


def test_train_resume_from_another_directory(runs, tmp_path, monkeypatch):
    """A run folder started here resumes from another working directory (paths stored absolute), and a resume
    of a finished run changes nothing in its metrics (no repeated rows)."""
    run = tmp_path / "run"
    shutil.copytree(runs / "run", run)
    rows = (run / "metrics.csv").read_text()
    monkeypatch.chdir(tmp_path.parent)
    assert main(["train", "--resume", str(run)]) == 0
    assert (run / "metrics.csv").read_text() == rows


HOSTILE = ["<script>document.title='owned'</script>", "<img src=x onerror=alert(1)>"]


class _Tags(html.parser.HTMLParser):
    """Every start tag of a page with its attribute names."""

    def __init__(self) -> None:
        super().__init__()
        self.tags: list[tuple[str, list[str]]] = []

    def handle_starttag(self, tag: str, attrs: list[tuple[str, str | None]]) -> None:
        self.tags.append((tag, [name for name, _ in attrs]))


@pytest.mark.parametrize("payload", HOSTILE)
def test_report_escapes_whatever_the_run_folder_holds(runs, tmp_path, payload):
    """Markup planted in config.json and eval.json (method, env id, seed, preset, numbers) reaches the page as
    text: no script element, no event-handler attribute, the planted text shown escaped."""
    run = tmp_path / "run"
    shutil.copytree(runs / "run", run)
    cfg = json.loads((run / "config.json").read_text())
    cfg.update(method=payload, env_id=payload, seed=payload, preset=payload, command=payload)
    cfg["train"] = {**cfg["train"], "iterations": payload}
    (run / "config.json").write_text(json.dumps(cfg))
    (run / "eval.json").write_text(json.dumps({"episodes": payload, "mean_return": payload, "std_return": payload,
                                               "success_rate": 0.5, "env_id": payload, "macro_policy": payload,
                                               "expert": {"mean_return": payload, "success_rate": 1.0}}))
    (run / "segmentation.json").write_text(json.dumps({"accuracy": 0.5, "matching": payload,
                                                       "mapping": {payload: payload}}))
    assert main(["report", str(run), "--no-figures"]) == 0
    page = (run / "report.html").read_text()
    parser = _Tags()
    parser.feed(page)
    assert parser.tags, "the page did not parse"
    assert "script" not in [tag for tag, _ in parser.tags]
    assert not [(tag, a) for tag, attrs in parser.tags for a in attrs if a.lower().startswith("on")]
    assert html.escape(payload) in page


def _digail(argv: list[str], fsize: int | None = None, script: str = "", **kwargs: object) -> subprocess.Popen:
    """`python -m digail.cli ARGV` in a child process, optionally under a file-size limit (`ulimit -f`) with
    SIGXFSZ ignored, so that a write past it fails with EFBIG as it does under a shell's limit; `script` runs
    first in the child (e.g. to move a threshold)."""
    def limit() -> None:
        if fsize is not None:
            signal.signal(signal.SIGXFSZ, signal.SIG_IGN)
            resource.setrlimit(resource.RLIMIT_FSIZE, (fsize, fsize))

    code = f"import sys\n{script}\nfrom digail.cli import main\nsys.exit(main(sys.argv[1:]))"
    env = kwargs.pop("env", {**os.environ, "MUJOCO_GL": "egl", "PYTHONPATH": os.pathsep.join(sys.path)})
    return subprocess.Popen([sys.executable, "-c", code, *argv], env=env, preexec_fn=limit,
                            stderr=subprocess.PIPE, text=True, **kwargs)  # type: ignore[call-overload]


def _leftovers(folder: Path) -> list[str]:
    return sorted(p.name for p in folder.iterdir() if ".tmp-" in p.name or ".old-" in p.name)


def test_a_small_file_size_limit_is_refused_before_any_work(runs, tmp_path):
    out = tmp_path / "vae"
    proc = _digail(["pretrain", "--demos", str(runs / "demos"), "--preset", "smoke", "--out", str(out)],
                   fsize=64 * 1024, stdout=subprocess.DEVNULL)
    _, err = proc.communicate(timeout=300)
    assert proc.returncode == 2, err
    assert err.strip().splitlines()[-1].startswith("digail pretrain: error: a file-size limit of 64 KiB"), err
    assert "Traceback" not in err and not out.exists() and not _leftovers(tmp_path)


def test_a_write_past_the_file_size_limit_is_one_sentence_and_leaves_nothing(runs, tmp_path):
    """Past the up-front check (its threshold moved to 0 here), a model file larger than the limit fails with
    EFBIG: one sentence, exit status 2, no output folder and no temporary one."""
    out = tmp_path / "vae"
    proc = _digail(["pretrain", "--demos", str(runs / "demos"), "--preset", "smoke", "--out", str(out)],
                   fsize=24 * 1024, script="import digail.fsio; digail.fsio.MIN_FREE_BYTES = 0",
                   stdout=subprocess.DEVNULL)
    _, err = proc.communicate(timeout=300)
    assert proc.returncode == 2, err
    assert err.strip().splitlines()[-1].startswith("digail pretrain: error: file too large"), err
    assert "ulimit -f" in err and "Traceback" not in err
    assert not out.exists() and not _leftovers(tmp_path)


@pytest.mark.parametrize("argv", [["pretrain", "--help"], ["--help"], ["evaluate", RUN, "--episodes", "2"]])
def test_output_into_a_closed_pipe_ends_quietly(runs, tmp_path, argv):
    """`digail ... | head` when head has already gone: no BrokenPipe traceback, the status of SIGPIPE."""
    shutil.copytree(runs / "run", tmp_path / "run")
    read_end, write_end = os.pipe()
    os.close(read_end)  # the reader is gone before the first line is written
    try:
        proc = _digail([a.format(tmp=tmp_path) for a in argv], stdout=write_end)
    finally:
        os.close(write_end)
    _, err = proc.communicate(timeout=300)
    assert proc.returncode == 128 + signal.SIGPIPE, err
    assert "Traceback" not in err and "BrokenPipe" not in err, err


@pytest.fixture(scope="module")
def mujoco_run(tmp_path_factory):
    """A run folder whose (untrained) model acts on InvertedPendulum-v5, a MuJoCo env."""
    from digail.checkpoint import save_model
    from digail.nets.policy import ActionSpec
    from digail.nets.vae import HierarchicalPolicy

    run = tmp_path_factory.mktemp("mujoco") / "run"
    run.mkdir()
    model = HierarchicalPolicy(4, 2, ActionSpec(False, 1))
    save_model(run / "model.pt", model, kind="vae", config={"env_id": "InvertedPendulum-v5"},
               env_id="InvertedPendulum-v5")
    (run / "config.json").write_text(json.dumps({"kind": "vae", "env_id": "InvertedPendulum-v5"}))
    return run


@pytest.mark.mujoco
@pytest.mark.parametrize("gl", ["bogus", "osmesa", "osmesa, PyOpenGL on egl"])
@pytest.mark.parametrize("command", ["video", "evaluate"])
def test_a_renderer_mujoco_cannot_start_is_one_sentence(mujoco_run, tmp_path, gl, command):
    """MUJOCO_GL set to a value MuJoCo refuses, or to osmesa where its library is missing (MuJoCo's import fails,
    or with PyOpenGL already on another platform its first frame does): one sentence naming MUJOCO_GL from the
    commands that render or step MuJoCo, exit status 2, nothing written."""
    import ctypes.util

    if gl.startswith("osmesa") and ctypes.util.find_library("OSMesa") is not None:
        pytest.skip("OSMesa is installed here")
    run = tmp_path / "run"
    shutil.copytree(mujoco_run, run)
    before = _snapshot(run)
    argv = [command, str(run), "--max-steps" if command == "video" else "--episodes", "2"]
    env = {k: v for k, v in os.environ.items() if k != "PYOPENGL_PLATFORM"}
    env.update(MUJOCO_GL=gl.split(",")[0], PYTHONPATH=os.pathsep.join(sys.path))
    if "PyOpenGL" in gl:
        env["PYOPENGL_PLATFORM"] = "egl"
    proc = _digail(argv, stdout=subprocess.DEVNULL, env=env)
    _, err = proc.communicate(timeout=300)
    if command == "evaluate" and "PyOpenGL" in gl:  # MuJoCo loads and evaluate draws nothing: it works
        assert proc.returncode == 0, err
        return
    assert proc.returncode == 2, err
    assert len(err.strip().splitlines()) == 1 and err.startswith(f"digail {command}: error: MUJOCO_GL="), err
    assert _snapshot(run) == before


@pytest.fixture
def held_run(runs, tmp_path):
    """A copy of the trained run folder held by another process as a live command holds it: an exclusive flock
    on RUN/.digail.lock, which holds the holder's process id."""
    run = tmp_path / "run"
    shutil.copytree(runs / "run", run)
    code = ("import fcntl, os, sys, time\n"
            "fd = os.open(os.path.join(sys.argv[1], '.digail.lock'), os.O_RDWR | os.O_CREAT)\n"
            "fcntl.flock(fd, fcntl.LOCK_EX)\nos.write(fd, f'{os.getpid()}\\n'.encode())\n"
            "print('held', flush=True)\ntime.sleep(600)\n")
    holder = subprocess.Popen([sys.executable, "-c", code, str(run)], stdout=subprocess.PIPE, text=True)
    assert holder.stdout is not None and holder.stdout.readline().strip() == "held"
    yield run, holder
    holder.kill()
    holder.wait()


SECOND_WRITERS = {
    "train --force": [*TRAIN[:-1], "{run}", "--force"],
    "train --resume": ["train", "--resume", "{run}"],
    "pretrain --force": ["pretrain", "--demos", "{demos}", "--preset", "smoke", "--out", "{run}", "--force"],
    "demos --force": ["demos", ENV, "--episodes", "2", "--out", "{run}", "--force"],
    "evaluate": ["evaluate", "{run}", "--episodes", "2"],
    "compose": ["compose", "{run}", "--schedule", "0:5", "--episodes", "2"],
    "segment": ["segment", "{run}"],
    "video": ["video", "{run}", "--max-steps", "3"],
    "report": ["report", "{run}", "--no-figures"],
    "expert": ["expert", "Pendulum-v1", "--out", "{run}", "--steps", "64"],
}


@pytest.mark.parametrize("name", list(SECOND_WRITERS))
def test_a_folder_another_command_writes_is_refused(name, runs, held_run, capsys):
    """While another process writes a run folder, every command that would write it (--force included) is
    refused in one sentence naming that process, and the folder is left as it is."""
    run, holder = held_run
    argv = [a.format(run=run, demos=runs / "demos", vae=runs / "vae", tmp=run.parent) for a in SECOND_WRITERS[name]]
    before = _snapshot(run)
    capsys.readouterr()
    assert main(argv) == 2, name
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "Traceback" not in err, err
    assert f"is being written by another digail command (process {holder.pid})" in err, err
    assert _snapshot(run) == before
    assert not _leftovers(run.parent)


def test_a_lock_left_by_a_killed_process_blocks_nothing(held_run, capsys):
    run, holder = held_run
    holder.kill()
    holder.wait()
    assert (run / ".digail.lock").is_file()  # the file stays; the kernel dropped the lock with the process
    assert main(["evaluate", str(run), "--episodes", "2"]) == 0, capsys.readouterr().err
    assert (run / "eval.json").is_file() and not (run / ".digail.lock").exists()


@pytest.mark.slow
def test_two_trainings_forced_into_one_folder(runs, tmp_path):
    """`digail train --out F --force` twice, the second started while the first trains: the second is refused
    and writes nothing; the first finishes with its own metrics."""
    out = tmp_path / "F"
    argv = ["train", "--demos", str(runs / "demos"), "--vae", str(runs / "vae"), "--preset", "smoke", "--out",
            str(out), "--force", "--train.iterations", "400"]
    first = _digail(argv, stdout=subprocess.DEVNULL)
    deadline = time.monotonic() + 240
    while not (out / ".digail.lock").exists():
        assert first.poll() is None and time.monotonic() < deadline, "the first training never started"
        time.sleep(0.05)
    second = _digail(argv, stdout=subprocess.DEVNULL)
    _, err = second.communicate(timeout=300)
    assert second.returncode == 2, err
    assert "is being written by another digail command" in err.strip().splitlines()[-1], err
    _, err = first.communicate(timeout=600)
    assert first.returncode == 0, err
    rows = (out / "metrics.csv").read_text().splitlines()
    iterations = [float(r.split(",")[rows[0].split(",").index("iteration")]) for r in rows[1:]]
    assert iterations == [float(i) for i in range(1, 401)]
    assert not (out / ".digail.lock").exists()
