"""Failure paths, fourth round: probes on sweep overrides, `--force`, imported files, demonstration subsets, replay
buffers, non-UTF-8 paths, lock files, composition schedules and resume paths.

Each probe is what a user might try and what digail must give back: either it is accepted, or it is refused with one
sentence holding the expected phrase (exit status 2 from the CLI, no traceback) and nothing in the probe's folder
changes. The same probes, with what each gets, are the table in the reliability page (docs/reference/errors.md).
"""

from __future__ import annotations

import contextlib
import io
import json
import os
import pickle
import zipfile
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import h5py
import numpy as np
import pytest

from digail.cli import main
from digail.errors import UserError

CW = "digail/CircleWorld-v0"
CW_DEMOS = "digail/circleworld/expert-v0"


@dataclass(frozen=True)
class Probe:
    id: str
    """a short name"""
    what: str
    """what was tried, in the docs' words"""
    run: Callable[[Path], object]
    """runs the probe in its own folder; raises UserError when refused"""
    expect: str | None
    """a phrase of the refusal, or None: accepted"""


PROBES: list[Probe] = []


def probe(pid: str, what: str, expect: str | None) -> Callable[[Callable[[Path], object]], Callable[[Path], object]]:
    def add(fn: Callable[[Path], object]) -> Callable[[Path], object]:
        PROBES.append(Probe(pid, what, fn, expect))
        return fn

    return add


def cli(tmp: Path, *argv: str) -> None:
    """Run `digail argv` in `tmp`; a refusal becomes the UserError of its one line."""
    err = io.StringIO()
    old = Path.cwd()
    os.chdir(tmp)
    try:
        with contextlib.redirect_stderr(err), contextlib.redirect_stdout(io.StringIO()):
            code = main(list(argv))
    finally:
        os.chdir(old)
    text = err.getvalue()
    assert "Traceback" not in text, text
    if code == 0:
        return
    lines = [ln for ln in text.splitlines() if ln.strip() and "is deprecated" not in ln]
    assert code == 2 and len(lines) == 1 and ": error: " in lines[0], (code, text)
    raise UserError(lines[0].split(": error: ", 1)[1])


# ------------------------------------------------------------------------------------------------ sweep overrides
def sweep_check(sets: tuple[str, ...] = (), spec: str | None = None, tmp: Path | None = None) -> None:
    """What `digail sweep` checks before Ray starts or a file is written."""
    from digail.commands.sweep import check_spec
    from digail.sweep.plan import plan
    from digail.sweep.spec import build_spec

    spec_file = None
    if spec is not None:
        assert tmp is not None
        spec_file = tmp / "spec.toml"
        spec_file.write_text(spec)
    built = build_spec(envs=None if spec else (CW,), methods=None if spec else ("vae", "digail"), sets=sets,
                       spec_file=spec_file, preset="smoke")
    check_spec(built, plan(built))


NOT_A_SETTING = "is not a setting a sweep may change"
for _key in ("pretrain.out", "pretrain.force", "pretrain.resume", "pretrain.demos", "pretrain.device", "pretrain.seed",
             "pretrain.preset", "pretrain.demos_episodes", "train.out", "train.resume", "train.vae", "train.demos",
             "train.device", "train.force", "train.method", "train.ppo", "train.sac", "evaluate.run", "evaluate.out",
             "segment.demos", "segment.run", "demos.path", "demos.dataset", "vae.codes.x"):
    probe(f"set-{_key}", f"`digail sweep --set {_key}=...`", NOT_A_SETTING)(
        lambda tmp, k=_key: sweep_check((f"{k}=x",)))

for _pid, _item, _expect in [
    ("set-upper", "Train.iterations=3", "names no stage option"),
    ("set-double-dot", "train..iterations=3", NOT_A_SETTING),
    ("set-below-leaf", "train.iterations.x=3", NOT_A_SETTING),
    ("set-flag-value", "train.bonus_weight=--out", "a value may not start with '-'"),
    ("set-flag-in-tuple", "train.hidden=64 --force", "a value may not start with '-'"),
    ("set-short-flag", "train.reward=-h", "a value may not start with '-'"),
    ("set-negative-number", "train.bonus_weight=-1", None),
    ("set-equals-in-value", "train.reward=a=b", "train.reward=a=b"),
    ("set-zero-episodes", "demos.episodes=0", "--demos-episodes must be at least 1"),
    ("set-nan", "train.bonus_weight=nan", "train.bonus_weight"),
    ("set-no-value", "train.iterations", "write KEY=VALUE"),
    ("set-ok-ppo-lr", "train.ppo.lr=1e-4", None),
    ("set-ok-kl", "vae.kl_weight=0.5", None),
    ("set-ok-subsample", "demos.subsample=2", None),
    ("set-ok-episodes", "demos.episodes=2", None),
    ("set-ok-codes", "pretrain.codes=3", None),
    ("set-vae-codes", "vae.codes=3", NOT_A_SETTING),
    ("set-ok-eval-episodes", "evaluate.episodes=5", None),
    ("set-ok-label-map", "segment.label_map=0 1", None),
    ("set-ok-sac-buffer", "train.sac.buffer_size=1000", None),
    ("set-ok-grid", "train.bonus_weight=0.01,0.1", None),
]:
    probe(_pid, f"`digail sweep --set {_item}`", _expect)(lambda tmp, i=_item: sweep_check((i,)))

for _pid, _text, _expect in [
    ("spec-set-out", f'envs = ["{CW}"]\n[set]\n"pretrain.out" = "/tmp"\n', NOT_A_SETTING),
    ("spec-grid-set-run", f'[[grid]]\nenvs = ["{CW}"]\nset = {{ "evaluate.run" = "x" }}\n', NOT_A_SETTING),
    ("spec-inner-list-flag", f'envs = ["{CW}"]\nset = {{ "train.hidden" = [[64, "--force"]] }}\n',
     "a value may not start with '-'"),
    ("spec-range-on-out", f'envs = ["{CW}"]\nset = {{ "train.out" = {{ low = 1, high = 2 }} }}\n', NOT_A_SETTING),
    ("spec-nested-list", f'envs = ["{CW}"]\nset = {{ "train.hidden" = [[[64]]] }}\n', "nests a list in a list"),
    ("spec-ok", f'envs = ["{CW}"]\nmethods = ["vae"]\nset = {{ "vae.kl_weight" = [0.5, 1.0] }}\n', None),
]:
    probe(_pid, f"a sweep spec: `{_text.splitlines()[-1]}`", _expect)(lambda tmp, t=_text: sweep_check(spec=t, tmp=tmp))


# ------------------------------------------------------------------------------------------------ --force
def force(target: str) -> Callable[[Path], None]:
    def run(tmp: Path) -> None:
        from digail.fsio import check_new_dir

        here = tmp / "a" / "inner"
        here.mkdir(parents=True, exist_ok=True)
        old = Path.cwd()
        os.chdir(here)
        try:
            check_new_dir(Path(target.replace("TMP", str(tmp))), force=True)
        finally:
            os.chdir(old)

    return run


def _setup_force(tmp: Path) -> None:
    if (tmp / "mine").exists():
        return
    (tmp / "mine").mkdir()
    (tmp / "mine" / "thesis.tex").write_text("a user's file\n")
    (tmp / "file").write_text("a user's file\n")
    (tmp / "link").symlink_to(tmp / "mine")
    (tmp / "dangling").symlink_to(tmp / "nowhere")
    (tmp / "loop").symlink_to(tmp / "loop")
    (tmp / "empty").mkdir()
    (tmp / "locked-empty").mkdir()
    (tmp / "locked-empty" / ".digail.lock").write_text("")
    (tmp / "marked").mkdir()
    (tmp / "marked" / ".digail").write_text("\n")
    (tmp / "marked" / "extra.txt").write_text("added later\n")
    (tmp / "marker-dir").mkdir()
    (tmp / "marker-dir" / ".digail").mkdir()
    (tmp / "marker-dir" / "thesis.tex").write_text("x\n")
    (tmp / "marked-link").symlink_to(tmp / "marked")
    (tmp / "oldrun").mkdir()
    (tmp / "oldrun" / "config.json").write_text(json.dumps({"env_id": CW, "seed": 0, "kind": "vae"}))
    (tmp / "oldrun" / "model.pt").write_bytes(b"x")
    (tmp / "otherconfig").mkdir()
    (tmp / "otherconfig" / "config.json").write_text(json.dumps({"lr": 0.1}))
    (tmp / "listconfig").mkdir()
    (tmp / "listconfig" / "config.json").write_text("[1]")
    for name, record in (("olddata", {"dataset_id": "x/y-v0", "digail": {}}), ("minari", {"dataset_id": "x/y-v0"})):
        (tmp / name / "data").mkdir(parents=True)
        (tmp / name / "data" / "metadata.json").write_text(json.dumps(record))
        (tmp / name / "data" / "main_data.hdf5").write_bytes(b"x")
    (tmp / "oldsweep" / "trials").mkdir(parents=True)
    (tmp / "oldsweep" / "sweep.json").write_text("{}")


for _pid, _target, _what, _expect in [
    ("force-users-folder", "TMP/mine", "a folder of the user's", "is not a folder digail made"),
    ("force-file", "TMP/file", "a file", "is a file, and --force replaces only a folder"),
    ("force-link-to-users", "TMP/link", "a link to a folder of the user's", "is not a folder digail made"),
    ("force-dangling-link", "TMP/dangling", "a link to nothing", "is a link to nothing"),
    ("force-link-loop", "TMP/loop", "a link to itself", "leads nowhere"),
    ("force-cwd", ".", "`.`, the current directory (even one digail made)", "the current directory"),
    ("force-parent", "..", "`..`", "a folder holding the current directory"),
    ("force-grandparent", "../..", "`../..`", "a folder holding the current directory"),
    ("force-cwd-absolute", "TMP/a/inner", "the current directory by its absolute path", "the current directory"),
    ("force-root", "/", "`/`", "--force would delete /, a filesystem root"),
    ("force-marker-folder", "TMP/marker-dir", "a folder whose `.digail` is a folder", "is not a folder digail made"),
    ("force-other-config", "TMP/otherconfig", "a folder whose config.json is another tool's",
     "is not a folder digail made"),
    ("force-list-config", "TMP/listconfig", "a folder whose config.json is a JSON list", "is not a folder digail made"),
    ("force-minari-not-digail", "TMP/minari", "a Minari dataset digail did not write", "is not a folder digail made"),
    ("force-empty", "TMP/empty", "an empty folder", None),
    ("force-lock-only", "TMP/locked-empty", "a folder holding only a stale lock file", None),
    ("force-marked", "TMP/marked", "a folder with the `.digail` marker", None),
    ("force-marked-link", "TMP/marked-link", "a link to a marked folder", None),
    ("force-old-run", "TMP/oldrun", "a run folder from before the marker (config.json with env_id and seed)", None),
    ("force-old-dataset", "TMP/olddata", "a dataset from before the marker (digail's record in its metadata)", None),
    ("force-old-sweep", "TMP/oldsweep", "a sweep folder from before the marker", None),
]:
    def _run(tmp: Path, target: str = _target) -> None:
        _setup_force(tmp)
        force(target)(tmp)

    probe(_pid, f"`--force` onto {_what}", _expect)(_run)


@probe("force-home", "`--force` onto the home folder (marked)", "the home folder")
def _force_home(tmp: Path) -> None:
    from digail.fsio import check_replaceable

    home = tmp / "home"
    home.mkdir()
    (home / ".digail").write_text("\n")
    old = os.environ.get("HOME")
    os.environ["HOME"] = str(home)
    try:
        check_replaceable(home)
    finally:
        if old is None:
            del os.environ["HOME"]
        else:
            os.environ["HOME"] = old


@probe("force-locked", "`--force` onto a marked folder another process is writing", "is being written by another")
def _force_locked(tmp: Path) -> None:
    import fcntl

    from digail.fsio import check_new_dir

    (tmp / "run").mkdir()
    (tmp / "run" / ".digail").write_text("\n")
    fd = os.open(tmp / "run" / ".digail.lock", os.O_RDWR | os.O_CREAT)
    try:
        fcntl.flock(fd, fcntl.LOCK_EX)
        check_new_dir(tmp / "run", force=True)
    finally:
        os.close(fd)


# ------------------------------------------------------------------------------------------------ imported files
def _good(n: int = 20) -> dict[str, np.ndarray]:
    rng = np.random.default_rng(2)
    return {"observations": rng.normal(size=(n, 3)).astype(np.float32),
            "actions": rng.normal(size=(n, 1)).astype(np.float32), "episode_ends": np.array([n // 2, n])}


def _d4rl(n: int = 20) -> dict[str, np.ndarray]:
    good = _good(n)
    terminals = np.zeros(n, bool)
    terminals[n // 2 - 1] = terminals[-1] = True
    return {"observations": good["observations"], "actions": good["actions"], "terminals": terminals}


def _header_npz(path: Path, key: str, shape: tuple[int, ...], fortran: bool = False) -> None:
    arrays = _good()
    head = io.BytesIO()
    descr = "<i8" if key == "episode_ends" else "<f4"
    np.lib.format.write_array_header_1_0(head, {"descr": descr, "fortran_order": fortran, "shape": shape})
    with zipfile.ZipFile(path, "w") as z:
        for k, arr in arrays.items():
            if k == key:
                z.writestr(f"{k}.npy", head.getvalue() + b"\0" * 64)
            else:
                buf = io.BytesIO()
                np.save(buf, arr)
                z.writestr(f"{k}.npy", buf.getvalue())


def _npz(**changes: object) -> Callable[[Path], None]:
    def make(path: Path) -> None:
        np.savez(path, **{**_good(), **changes})

    return make


def _h5(**changes: object) -> Callable[[Path], None]:
    def make(path: Path) -> None:
        with h5py.File(path, "w") as f:
            for key, value in {**_d4rl(), **changes}.items():
                if value is None:
                    continue
                if isinstance(value, tuple):  # declared (shape, chunks), never written
                    f.create_dataset(key, shape=value[0], dtype="f4", chunks=value[1])
                elif isinstance(value, dict):  # a group where an array belongs
                    f.create_group(key)
                else:
                    f[key] = value

    return make


def _cut(make: Callable[[Path], None], keep: float | int) -> Callable[[Path], None]:
    def cut(path: Path) -> None:
        make(path)
        data = path.read_bytes()
        path.write_bytes(data[: int(len(data) * keep) if isinstance(keep, float) else keep])

    return cut


def _damaged_member(path: Path) -> None:
    np.savez_compressed(path, **_good())
    data = bytearray(path.read_bytes())
    data[60:80] = bytes(20)
    path.write_bytes(bytes(data))


def _raw(data: bytes) -> Callable[[Path], None]:
    return lambda path: path.write_bytes(data)


GOOD = _npz()
IMPORT_PROBES: list[tuple[str, str, str, Callable[[Path], None], str | None]] = [
    # id, file name, what, how it is made, expected phrase (None: imported)
    ("npz-half", "d.npz", "an .npz cut in half", _cut(GOOD, 0.5), "as an .npz file"),
    ("npz-empty", "d.npz", "an empty .npz (0 bytes)", _raw(b""), "as an .npz file"),
    ("npz-10-bytes", "d.npz", "an .npz cut to 10 bytes", _cut(GOOD, 10), "as an .npz file"),
    ("npz-last-byte", "d.npz", "an .npz without its last byte", _cut(GOOD, -1), "as an .npz file"),
    ("npz-member-damaged", "d.npz", "a compressed .npz with a damaged member", _damaged_member, "the file is damaged"),
    ("npz-huge-obs", "d.npz", "an .npz whose header declares 10^12 x 3 observations",
     lambda p: _header_npz(p, "observations", (10**12, 3)), "declares 'observations' as a (1000000000000, 3) array"),
    ("npz-huge-ends", "d.npz", "an .npz whose header declares 10^15 episode ends",
     lambda p: _header_npz(p, "episode_ends", (10**15,)), "declares 'episode_ends' as a (1000000000000000,) array"),
    ("npz-huge-fortran", "d.npz", "a huge Fortran-order header", lambda p: _header_npz(p, "actions", (10**12, 1), True),
     "declares 'actions' as a (1000000000000, 1) array"),
    ("npz-complex-obs", "d.npz", "complex observations", _npz(observations=_good()["observations"] + 1j),
     "complex values in 'observations'"),
    ("npz-complex-acts", "d.npz", "complex actions", _npz(actions=_good()["actions"] * 1j),
     "complex values in 'actions'"),
    ("npz-1e300-obs", "d.npz", "float64 observations of 1e300 (finite, beyond float32)",
     _npz(observations=_good()["observations"].astype(np.float64) * 1e300), "beyond float32's range"),
    ("npz-1e39-acts", "d.npz", "float64 actions of 1e39", _npz(actions=np.full((20, 1), 1e39)),
     "beyond float32's range"),
    ("npz-1e300-rews", "d.npz", "float64 rewards of 1e300", _npz(rewards=np.full(20, 1e300)), "beyond float32's range"),
    ("npz-nan", "d.npz", "a NaN observation", _npz(observations=np.where(np.eye(20, 3) > 0, np.nan, 0.0)),
     "NaN or inf values in 'observations'"),
    ("npz-inf-acts", "d.npz", "an inf action", _npz(actions=np.full((20, 1), np.inf)),
     "NaN or inf values in 'actions'"),
    ("npz-strings", "d.npz", "observations as strings", _npz(observations=np.array(["a"] * 20)),
     "'observations' of dtype <U1"),
    ("npz-structured", "d.npz", "a structured array", _npz(observations=np.zeros(20, dtype=[("x", "f4")])),
     "it must be a numeric array"),
    ("npz-object", "d.npz", "an object array (pickled)", _npz(observations=np.array([None] * 20, dtype=object)),
     "pickled Python objects"),
    ("npz-raw-pickle", "d.npz", "a raw pickle named .npz", _raw(pickle.dumps({"observations": [1.0]})),
     "is a Python pickle, not an .npz file"),
    ("npz-text", "d.npz", "a text file named .npz", _raw(b"observations,actions\n1,2\n"),
     "neither a zip archive nor an .npy array"),
    ("npz-single-npy", "d.npz", "a single .npy array named .npz", lambda p: p.write_bytes(_npy(np.zeros(3))),
     "holds a single array"),
    ("npz-scalar-obs", "d.npz", "a 0-d observations array", _npz(observations=np.float32(1.0)),
     "'observations' as a single number"),
    ("npz-scalar-ends", "d.npz", "a 0-d episode_ends", _npz(episode_ends=np.int64(20)), "'episode_ends' as a single"),
    ("imitation-scalar-obs", "d.npz", "imitation with 0-d observations",
     lambda p: np.savez(p, obs=np.float32(0), acts=np.zeros((20, 1)), indices=np.array([10]),
                        terminal=np.ones(2, bool)), "'obs' as a single number"),
    ("npz-no-steps", "d.npz", "zero-length arrays", _npz(observations=np.zeros((0, 3)), actions=np.zeros((0, 1)),
                                                        episode_ends=np.zeros(0, int)), "'episode_ends' that are not"),
    ("npz-ends-short", "d.npz", "episode ends short of the steps", _npz(episode_ends=np.array([5, 10])),
     "'episode_ends' that are not"),
    ("npz-unknown-layout", "d.npz", "arrays of no known layout", lambda p: np.savez(p, x=np.zeros(3)),
     "none of the layouts digail reads"),
    ("npz-bool-obs", "d.npz", "boolean observations", _npz(observations=np.zeros((20, 3), bool)), None),
    ("npz-int-obs", "d.npz", "integer observations", _npz(observations=np.arange(60).reshape(20, 3)), None),
    ("npz-upper-suffix", "D.NPZ", "a good file named D.NPZ", GOOD, None),
    ("npz-folder", "d.npz", "a folder named d.npz", lambda p: p.mkdir(), "is a folder"),
    ("sb3-starts-3d", "d.npz", "SB3 episode_starts of 3 dimensions",
     lambda p: np.savez(p, obs=np.zeros((4, 2, 3)), actions=np.zeros((4, 2, 1)), episode_starts=np.zeros((4, 2, 1))),
     "'episode_starts' of shape (4, 2, 1)"),
    ("imitation-indices-down", "d.npz", "imitation indices that go down",
     lambda p: np.savez(p, obs=np.zeros((23, 3)), acts=np.zeros((20, 1)), indices=np.array([10, 5]),
                        terminal=np.ones(3, bool)), "not strictly increasing"),
    ("h5-empty", "d.hdf5", "an empty HDF5 file (0 bytes)", _raw(b""), "as an HDF5 file"),
    ("h5-half", "d.hdf5", "an HDF5 file cut in half", _cut(_h5(), 0.5), "the file is damaged"),
    ("h5-terminals-2d", "d.hdf5", "D4RL terminals of shape (20, 2)", _h5(terminals=np.zeros((20, 2), bool)),
     "'terminals' of shape (20, 2)"),
    ("h5-timeouts-2d", "d.hdf5", "D4RL timeouts of shape (20, 1)", _h5(timeouts=np.zeros((20, 1), bool)),
     "'timeouts' of shape (20, 1)"),
    ("h5-terminals-half", "d.hdf5", "terminals of 0.5", _h5(terminals=np.full(20, 0.5)),
     "values other than True/False"),
    ("h5-obs-group", "d.hdf5", "observations as an HDF5 group", _h5(observations={}), "has no 'observations' array"),
    ("h5-vlen-strings", "d.hdf5", "observations as variable-length strings",
     _h5(observations=np.array(["a"] * 20, dtype=h5py.string_dtype())), "it must be a numeric array"),
    ("h5-huge-chunked", "d.hdf5", "a chunked dataset declaring 10^12 x 3 float32",
     _h5(observations=((10**12, 3), (1024, 3))), "of memory available"),
    ("h5-huge-contiguous", "d.hdf5", "a contiguous dataset declaring 10^11 x 3 float32, never written",
     _h5(observations=((10**11, 3), None)), "the file is damaged or cut short"),
    ("h5-complex", "d.hdf5", "complex observations in HDF5", _h5(observations=_d4rl()["observations"] * 1j),
     "complex values in 'observations'"),
    ("h5-1e300-next", "d.hdf5", "next_observations of 1e300",
     _h5(next_observations=np.full((20, 3), 1e300)), "beyond float32's range"),
    ("h5-no-flags", "d.hdf5", "neither terminals nor timeouts", _h5(terminals=None, timeouts=None),
     "none of the layouts"),
    ("h5-good", "d.h5", "a good D4RL file named .h5", _h5(), None),
]


def _npy(arr: np.ndarray) -> bytes:
    buf = io.BytesIO()
    np.save(buf, arr)
    return buf.getvalue()


for _pid, _name, _what, _make, _expect in IMPORT_PROBES:
    def _run_import(tmp: Path, name: str = _name, make: Callable[[Path], None] = _make) -> None:
        made = tmp / ("made.npz" if name.lower().endswith(".npz") else "made.hdf5")
        make(made)  # numpy adds .npz to a name without it (D.NPZ): made under a lower-case name, then renamed
        made.rename(tmp / name)
        cli(tmp, "import", name, "--out", "out")

    probe(f"import-{_pid}", f"`digail import` {_what}", _expect)(_run_import)


# ------------------------------------------------------------------------------------------------ subsets
def _subset(episodes: int | None, every: int) -> Callable[[Path], None]:
    def run(_: Path) -> None:
        from digail.data.minari_io import load_dataset
        from digail.data.subset import select_demos

        trajs = list(load_dataset(CW_DEMOS).trajs)[:3]
        select_demos(trajs, episodes, every)

    return run


for _pid, _episodes, _every, _expect in [
    ("subset-zero-episodes", 0, 1, "--demos-episodes must be at least 1"),
    ("subset-too-many", 4, 1, "asks for more episodes than the dataset's 3"),
    ("subset-every-zero", None, 0, "--demos-subsample must be at least 1"),
    ("subset-every-longest", None, 120, "at least as long as every demonstration"),
    ("subset-every-huge", None, 10**9, "at least as long as every demonstration"),
    ("subset-every-longest-minus-1", None, 119, None),
    ("subset-one-every-20", 1, 20, None),
]:
    probe(_pid, f"demonstration subset: episodes {_episodes}, every {_every}-th (3 episodes of 120 transitions)",
          _expect)(_subset(_episodes, _every))


@probe("cli-pretrain-subsample", "`digail pretrain --demos-subsample 100000`", "at least as long as every")
def _cli_subsample(tmp: Path) -> None:
    cli(tmp, "pretrain", "--demos", CW_DEMOS, "--preset", "smoke", "--demos-subsample", "100000", "--out", "vae")


@probe("cli-run-episodes", "`digail run --demos-episodes 100000` (nothing left to block the corrected command)",
       "asks for more episodes")
def _cli_run_episodes(tmp: Path) -> None:
    cli(tmp, "run", CW, "--preset", "smoke", "--demos-episodes", "100000", "--out", "run")


# ------------------------------------------------------------------------------------------------ replay buffers
def _replay(change: dict[str, object], capacity: int = 8, obs_dim: int = 2) -> Callable[[Path], None]:
    def run(_: Path) -> None:
        from digail.algos.replay import ReplayBuffer

        buf = ReplayBuffer(8, obs_dim=2, act_dim=1, codes=3)
        rng = np.random.default_rng(0)
        buf.add(rng.normal(size=(5, 2)), rng.integers(3, size=5), rng.normal(size=(5, 1)), rng.normal(size=(5, 2)),
                rng.integers(3, size=5), np.zeros(5, bool), rng.normal(size=5), rng.normal(size=5))
        state = dict(buf.state_dict())
        for key, value in change.items():
            if isinstance(value, float) or key in ("codes", "next_codes"):
                arr = state[key].clone()
                arr.view(-1)[-1] = value
                state[key] = arr
            else:
                state[key] = value
        ReplayBuffer(capacity, obs_dim=obs_dim, act_dim=1, codes=3).load_state_dict(state)

    return run


for _pid, _change, _what, _expect, _kw in [
    ("replay-pos", {"pos": 3}, "write position moved", "write position 3", {}),
    ("replay-size-up", {"size": 8}, "size raised to the capacity", "records 8 transitions but holds 5", {}),
    ("replay-size-over", {"size": 9}, "size above the capacity", "records 9 transitions", {}),
    ("replay-size-negative", {"size": -1}, "negative size", "records -1 transitions", {}),
    ("replay-nan-next-obs", {"next_obs": float("nan")}, "a NaN next observation", "NaN or inf values in 'next_obs'",
     {}),
    ("replay-inf-rews", {"rews": float("inf")}, "an inf reward", "NaN or inf values in 'rews'", {}),
    ("replay-code-too-big", {"next_codes": 7}, "a code beyond K", "codes this model does not have", {}),
    ("replay-code-negative", {"codes": -2}, "a negative code", "codes this model does not have", {}),
    ("replay-capacity", {}, "another --train.sac.buffer-size at resume", "holds 8 transitions, this run's 16",
     {"capacity": 16}),
    ("replay-obs-width", {}, "another observation size", "does not fit this model's observations", {"obs_dim": 3}),
    ("replay-intact", {}, "an intact buffer", None, {}),
]:
    probe(_pid, f"a checkpoint's replay buffer: {_what}", _expect)(_replay(_change, **_kw))


@probe("replay-huge", "`--train.sac.buffer-size 10^12` (Hopper's sizes: 146 TiB)", "of memory is available")
def _replay_huge(_: Path) -> None:
    from digail.algos.replay import ReplayBuffer

    ReplayBuffer(10**12, obs_dim=11, act_dim=3, codes=4)


# ------------------------------------------------------------------------------------------------ paths and locks
BAD = "r\udcffn"
SHOWN = "r\\xffn"
for _pid, _argv in [
    ("utf8-train-out", ["train", "--method", "gail", "--demos", CW_DEMOS, "--out", BAD]),
    ("utf8-pretrain-demos", ["pretrain", "--demos", BAD]),
    ("utf8-train-vae", ["train", "--demos", CW_DEMOS, "--vae", BAD]),
    ("utf8-sweep-spec", ["sweep", "--spec", BAD + ".toml", "--out", "s"]),
    ("utf8-evaluate-run", ["evaluate", BAD]),
    ("utf8-report", ["report", BAD]),
    ("utf8-import-source", ["import", BAD + ".npz"]),
    ("utf8-run-out", ["run", CW, "--out", BAD]),
]:
    _shown = " ".join(a.replace(BAD, SHOWN) for a in _argv)
    probe(_pid, f"`digail {_shown}` (a name with the byte 0xff)", "is not valid UTF-8")(
        lambda tmp, a=tuple(_argv): cli(tmp, *a))


@probe("utf8-accented", "`digail import` into a UTF-8 name with accents (`données`)", None)
def _utf8_ok(tmp: Path) -> None:
    GOOD(tmp / "d.npz")
    cli(tmp, "import", "d.npz", "--out", "données")


@probe("lock-folder", "a run folder whose `.digail.lock` is a folder", "is a folder, not digail's lock file")
def _lock_folder(tmp: Path) -> None:
    (tmp / "run" / ".digail.lock").mkdir(parents=True)
    cli(tmp, "segment", "run")


@probe("lock-dangling-link", "a run folder whose `.digail.lock` is a link to a file elsewhere (not created)",
       "is a link, not digail's lock file")
def _lock_dangling(tmp: Path) -> None:
    from digail.fsio import run_dir_lock

    (tmp / "run").mkdir()
    (tmp / "run" / ".digail.lock").symlink_to(tmp / "elsewhere")
    try:
        with run_dir_lock(tmp / "run"):
            pass
    finally:
        assert not (tmp / "elsewhere").exists(), "the lock was written outside the run folder"


@probe("lock-link-to-file", "a run folder whose `.digail.lock` is a link to a user's file", "is a link")
def _lock_link(tmp: Path) -> None:
    from digail.fsio import run_dir_lock

    (tmp / "run").mkdir()
    (tmp / "notes.txt").write_text("a user's file\n")
    (tmp / "run" / ".digail.lock").symlink_to(tmp / "notes.txt")
    try:
        with run_dir_lock(tmp / "run"):
            pass
    finally:
        assert (tmp / "notes.txt").read_text() == "a user's file\n", "the lock wrote into a user's file"


# ------------------------------------------------------------------------------------------------ schedules
for _pid, _text, _expect in [
    ("compose-ok", "1:60,0:60", None),
    ("compose-spaces", " 1 : 60 , 0:60 ", None),
    ("compose-empty", "", "cannot read the schedule"),
    ("compose-zero-steps", "0:0", "at least 1"),
    ("compose-code-too-big", "9:10", "uses code 9 but the policy has 2 codes"),
    ("compose-trailing-comma", "0:60,", "cannot read the schedule"),
    ("compose-negative", "0:-5", "cannot read the schedule"),
    ("compose-arabic-digits", "٠:١٠", "cannot read the schedule"),
    ("compose-huge", "0:" + "9" * 30, "longer than an episode"),
    ("compose-too-long", "0:100,1:100", "longer than an episode (120 steps at most)"),
]:
    probe(_pid, f"`digail compose --schedule '{_text}'` (K = 2, episodes of 120 steps)", _expect)(
        lambda tmp, t=_text: __import__("digail.eval.composition", fromlist=["x"]).parse_schedule(t, 2, 120))


RUN = Path(__file__).resolve().parents[1] / "benchmarks" / "results" / "runs" / "pendulum_vae_s2"
"""a committed run folder (a Pendulum VAE): the analysis commands' probes work on a copy of it"""


def _on_run(*argv: str, damage: str | None = None) -> Callable[[Path], None]:
    def run(tmp: Path) -> None:
        import shutil

        shutil.copytree(RUN, tmp / "run")
        if damage is not None:
            data = (tmp / "run" / damage).read_bytes()
            (tmp / "run" / damage).write_bytes(data[: len(data) // 2])
        cli(tmp, *argv)

    return run


for _pid, _argv, _damage, _expect in [
    ("compose-cli-code", ["compose", "run", "--schedule", "9:10", "--episodes", "1"], None,
     "uses code 9 but the policy has"),
    ("compose-cli-episodes", ["compose", "run", "--episodes", "0"], None, "--episodes must be at least 1"),
    ("compose-cli-truncated-model", ["compose", "run", "--schedule", "0:10", "--episodes", "1"], "model.pt",
     "is corrupt, truncated or not a digail file"),
    ("evaluate-cli-episodes", ["evaluate", "run", "--episodes", "0"], None, "--episodes must be at least 1"),
    ("evaluate-cli-seed", ["evaluate", "run", "--seed", "-1"], None, "--seed must be between"),
    ("evaluate-cli-truncated-config", ["evaluate", "run", "--episodes", "1"], "config.json", "is not valid JSON"),
    ("segment-cli-users-demos", ["segment", "run", "--demos", "nowhere/nothing-v0"], None, "nowhere/nothing-v0"),
    ("report-cli-users-folder", ["report", "mine"], None, "mine"),
]:
    def _run_on(tmp: Path, argv: tuple[str, ...] = tuple(_argv), damage: str | None = _damage) -> None:
        (tmp / "mine").mkdir()
        (tmp / "mine" / "thesis.tex").write_text("x\n")
        _on_run(*argv, damage=damage)(tmp)

    probe(_pid, f"`digail {' '.join(_argv)}` on a copy of a committed Pendulum VAE run"
          + (f" with its {_damage} cut in half" if _damage else ""), _expect)(_run_on)


# ------------------------------------------------------------------------------------------------ resume paths
def _config(tmp: Path, data: object) -> None:
    (tmp / "run").mkdir(exist_ok=True)
    (tmp / "run" / "config.json").write_text(json.dumps(data))


for _pid, _what, _setup, _argv, _expect in [
    ("resume-missing", "`digail train --resume` a folder that does not exist", None, ["train", "--resume", "nope"],
     "does not exist"),
    ("resume-vae", "`digail train --resume` a VAE folder", {"kind": "vae", "env_id": CW, "seed": 0},
     ["train", "--resume", "run"], "is a VAE run folder"),
    ("resume-list-config", "`digail train --resume` a folder whose config.json is a list", [1, 2],
     ["train", "--resume", "run"], "does not hold a JSON object"),
    ("resume-no-args", "`digail train --resume` a folder whose config.json records no arguments",
     {"kind": "digail", "env_id": CW, "seed": 0}, ["train", "--resume", "run"], "records no training arguments"),
    ("resume-bad-args", "`digail train --resume` a folder whose recorded arguments are not a training's",
     {"kind": "digail", "args": {"seed": "zero", "nonsense": 1}}, ["train", "--resume", "run"],
     "training arguments in run/config.json are invalid"),
    ("resume-run-on-train", "`digail run --resume` a `digail train` folder",
     {"kind": "digail", "args": {"seed": 0}}, ["run", "--resume", "run"], "is not a folder made by `digail run`"),
    ("resume-run-users", "`digail run --resume` a folder of the user's", "users", ["run", "--resume", "run"],
     "is not a folder made by `digail run`"),
]:
    def _run_resume(tmp: Path, setup: object = _setup, argv: tuple[str, ...] = tuple(_argv)) -> None:
        if setup == "users":
            (tmp / "run").mkdir()
            (tmp / "run" / "thesis.tex").write_text("x\n")
        elif setup is not None:
            _config(tmp, setup)
        cli(tmp, *argv)

    probe(_pid, _what, _expect)(_run_resume)


# ------------------------------------------------------------------------------------------------ the test
def _tree(path: Path) -> dict[str, bytes | str]:
    out: dict[str, bytes | str] = {}
    for p in sorted(path.rglob("*")):
        if p.is_symlink():
            out[str(p.relative_to(path))] = "-> " + os.readlink(p)
        elif p.is_file():
            out[str(p.relative_to(path))] = p.read_bytes()
        elif p.is_dir():
            out[str(p.relative_to(path))] = "dir"
    return out


def outcome(p: Probe, tmp: Path) -> str | None:
    """The probe's sentence when refused, None when accepted."""
    try:
        p.run(tmp)
    except UserError as exc:
        return " ".join(str(exc).split())
    return None


@pytest.mark.parametrize("p", PROBES, ids=[p.id for p in PROBES])
def test_probe(p: Probe, tmp_path: Path) -> None:
    before: dict[str, bytes | str] | None = None
    if p.id.startswith("force-") and p.id not in ("force-home", "force-locked"):
        _setup_force(tmp_path)
        before = _tree(tmp_path)
    sentence = outcome(p, tmp_path)
    if p.expect is None:
        assert sentence is None, f"{p.id} was refused: {sentence}"
        return
    assert sentence is not None, f"{p.id} was accepted"
    assert p.expect in sentence, sentence
    assert "\n" not in sentence and "Traceback" not in sentence
    if before is not None:
        after = _tree(tmp_path)
        after.pop("a", None), before.pop("a", None)
        assert {k: v for k, v in after.items() if not k.startswith("a")} == \
            {k: v for k, v in before.items() if not k.startswith("a")}, "a refused --force changed a folder"
    for out in ("out", "vae", "run-new"):
        assert not (tmp_path / out).exists() or p.id.startswith("force-"), f"{p.id} wrote {out}"


def test_at_least_a_hundred_probes() -> None:
    assert len(PROBES) >= 100 and len({p.id for p in PROBES}) == len(PROBES)


def test_the_reliability_page_lists_every_probe() -> None:
    """docs/reference/errors.md publishes these probes: one row each, under the same words."""
    page = (Path(__file__).resolve().parents[1] / "docs" / "reference" / "errors.md").read_text()
    section = page.split("## Probes\n", 1)[1].split("\n## ", 1)[0].split("::: digail.errors", 1)[0]
    rows = [ln for ln in section.splitlines() if ln.startswith("| ") and not ln.startswith(("| tried", "| ---"))]
    assert len(rows) == len(PROBES)
    missing = [p.id for p in PROBES if f"| {p.what.replace('|', chr(92) + '|')} |" not in section]
    assert not missing, f"probes without a row in the reliability page: {missing}"
