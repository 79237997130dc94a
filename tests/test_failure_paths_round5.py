"""Failure paths, fifth round (the data side): `digail segment --export` never writes over what it read, the run or
a user's file; what the importers read stays inside the input; robomimic, LeRobot and imitation files that are
damaged, hostile or odd get one sentence.

Each probe is what a user might try and what digail must give back: either it is accepted, or it is refused with one
sentence holding the expected phrase (exit status 2 from the CLI, no traceback) and nothing in the probe's folder
changes (the source, the run folder and its dataset included). The same probes, with what each gets, are the
fifth round's table in the reliability page (docs/reference/errors.md; `python scripts/probe_table.py --round 5`).
"""

from __future__ import annotations

import contextlib
import io
import json
import os
import shutil
import signal
import socket
import subprocess
import sys
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import h5py
import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq
import pytest
from test_failure_paths_round4 import cli

from digail.cli import main
from digail.errors import UserError

ROOT = Path(__file__).resolve().parents[1]
IMITATION_DIR = ROOT / "tests" / "data" / "formats" / "imitation_dataset"
OBS_WIDTHS = {"a": 2, "b": 1}
"""the hand-made robomimic file's observation keys and widths (3 in all, as the LeRobot one's observation.state)"""
ACT_DIM = 2


@dataclass(frozen=True)
class Probe:
    id: str
    """a short name"""
    what: str
    """what was tried, in the docs' words"""
    run: Callable[[Path], object]
    """runs the probe in its own folder (a copy of the base folder: src.hdf5, lr/, demos/, vae/); raises UserError
    when refused"""
    expect: str | None
    """a phrase of the refusal, or None: accepted"""
    setup: Callable[[Path], object] | None = None
    """makes what the probe tries on in its folder, before the folder's contents are recorded"""


PROBES: list[Probe] = []


def probe(pid: str, what: str, expect: str | None, setup: Callable[[Path], object] | None = None
          ) -> Callable[[Callable[[Path], object]], Callable[[Path], object]]:
    def add(fn: Callable[[Path], object]) -> Callable[[Path], object]:
        PROBES.append(Probe(pid, what, fn, expect, setup))
        return fn

    return add


# ------------------------------------------------------------------------------------------------ fixtures
def robomimic(path: Path, n_demos: int = 3, steps: int = 12, keys: tuple[str, ...] = ("a", "b"),
              edit: Callable[[h5py.File], None] | None = None) -> Path:
    """A small robomimic file: `n_demos` demonstrations of `steps` steps, observation keys `keys` (OBS_WIDTHS)."""
    rng = np.random.default_rng(0)
    with h5py.File(path, "w") as f:
        data = f.create_group("data")
        data.attrs["env_args"] = json.dumps({"env_name": "Lift"})
        for i in range(n_demos):
            demo = data.create_group(f"demo_{i}")
            demo["actions"] = rng.normal(size=(steps, ACT_DIM)).astype(np.float32)
            demo["rewards"] = np.zeros(steps, np.float32)
            for key in keys:
                demo[f"obs/{key}"] = rng.normal(size=(steps, OBS_WIDTHS[key])).astype(np.float32)
                demo[f"next_obs/{key}"] = rng.normal(size=(steps, OBS_WIDTHS[key])).astype(np.float32)
        if edit is not None:
            edit(f)
    return path


def lerobot(folder: Path, episodes: int = 3, frames: int = 10, state: object = None, rows: int | None = None) -> Path:
    """A small LeRobot v3.0 dataset: `episodes` episodes of `frames` frames, a 3-wide observation.state; `state`
    replaces that column (a pyarrow array), `rows` keeps only the first rows."""
    rng = np.random.default_rng(1)
    n = episodes * frames
    columns = {
        "observation.state": pa.array(rng.normal(size=(n, 3)).astype(np.float32).tolist(), pa.list_(pa.float32(), 3)),
        "action": pa.array(rng.normal(size=(n, ACT_DIM)).astype(np.float32).tolist(), pa.list_(pa.float32(), ACT_DIM)),
        "episode_index": pa.array(np.repeat(np.arange(episodes), frames)),
        "frame_index": pa.array(np.tile(np.arange(frames), episodes)),
        "index": pa.array(np.arange(n)),
    }
    if state is not None:
        columns["observation.state"] = state
    table = pa.table(columns)
    if rows is not None:
        table = table.slice(0, rows)
    (folder / "meta").mkdir(parents=True)
    (folder / "data" / "chunk-000").mkdir(parents=True)
    features = {"observation.state": {"dtype": "float32", "shape": [3], "names": None},
                "action": {"dtype": "float32", "shape": [ACT_DIM], "names": None},
                **{k: {"dtype": "int64", "shape": [1], "names": None} for k in ("episode_index", "frame_index",
                                                                                "index")}}
    (folder / "meta" / "info.json").write_text(json.dumps({"codebase_version": "v3.0", "fps": 10,
                                                           "features": features}))
    pq.write_table(table, folder / "data" / "chunk-000" / "file-000.parquet")
    return folder


@pytest.fixture(scope="module")
def base(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return make_base(tmp_path_factory.mktemp("round5"))


def make_base(root: Path) -> Path:
    """src.hdf5 (robomimic, keys a and b), lr/ (LeRobot), demos/ (the Minari import of src.hdf5), vae/ (a SMOKE VAE
    of 2 codes pre-trained on demos), a user's notes.txt and folder sub/, in `root`; each probe works on a copy."""
    robomimic(root / "src.hdf5")
    lerobot(root / "lr")
    (root / "notes.txt").write_text("a user's file\n")
    (root / "sub").mkdir()
    (root / "sub" / "thesis.tex").write_text("a user's file\n")
    old = Path.cwd()
    os.chdir(root)
    try:
        with contextlib.redirect_stdout(io.StringIO()), contextlib.redirect_stderr(io.StringIO()):
            assert main(["import", "src.hdf5", "--out", "demos"]) == 0
            assert main(["pretrain", "--demos", "demos", "--codes", "2", "--preset", "smoke", "--out", "vae"]) == 0
    finally:
        os.chdir(old)
    return root


def _copy_base(base: Path, tmp: Path) -> None:
    for child in base.iterdir():
        target = tmp / child.name
        if child.is_dir():
            shutil.copytree(child, target, symlinks=True)
        else:
            shutil.copy2(child, target)
    # the dataset's record names the source by its absolute path: point it at this copy's source
    meta = tmp / "demos" / "data" / "metadata.json"
    meta.write_text(meta.read_text().replace(str(base), str(tmp)))
    config = tmp / "vae" / "config.json"
    config.write_text(config.read_text().replace(str(base), str(tmp)))


def segment(*argv: str) -> Callable[[Path], None]:
    return lambda tmp: cli(tmp, "segment", "vae", *argv)


# ------------------------------------------------------------------------------------------------ exports
for _pid, _argv, _what, _expect in [
    ("export-csv-over-source", ["--demos", "src.hdf5", "--export", "csv", "--out", "src.hdf5", "--force"],
     "a csv export over the robomimic source, with `--force`", "is the input"),
    ("export-json-over-lerobot-info", ["--demos", "lr", "--export", "json", "--out", "lr/meta/info.json", "--force"],
     "a json export over the LeRobot source's `meta/info.json`, with `--force`", "is inside the input"),
    ("export-csv-over-run-dataset", ["--demos", "src.hdf5", "--export", "csv", "--out",
                                     "demos/data/main_data.hdf5", "--force"],
     "a csv export over the run's dataset file, with `--force`", "is inside the run's dataset"),
    ("export-lerobot-over-run-dataset", ["--demos", "lr", "--export", "lerobot", "--out", "demos", "--force"],
     "a LeRobot export over the run's Minari dataset, with `--force`", "is the run's dataset"),
    ("export-lerobot-over-run", ["--demos", "lr", "--export", "lerobot", "--out", "vae", "--force"],
     "a LeRobot export over the run folder itself, with `--force`", "is the run folder"),
    ("export-lerobot-holding-source", ["--demos", "lr", "--export", "lerobot", "--out", ".", "--force"],
     "a LeRobot export over `.`, the folder holding the source and the run, with `--force`", "--out . holds"),
    ("export-robomimic-over-model", ["--demos", "src.hdf5", "--export", "robomimic", "--out", "vae/model.pt",
                                     "--force"], "a robomimic export over the run's `model.pt`, with `--force`",
     "is inside the run folder"),
    ("export-csv-over-config", ["--demos", "src.hdf5", "--export", "csv", "--out", "vae/config.json", "--force"],
     "a csv export over the run's `config.json`, with `--force`", "is inside the run folder"),
    ("export-csv-new-in-run", ["--demos", "src.hdf5", "--export", "csv", "--out", "vae/seg.csv"],
     "a new csv file inside the run folder", "is inside the run folder"),
    ("export-from-dataset-over-source", ["--export", "csv", "--out", "src.hdf5", "--force"],
     "a csv export (of the run's own dataset) over the file it was imported from, with `--force`", "is the input"),
    ("export-csv-over-users-file", ["--demos", "src.hdf5", "--export", "csv", "--out", "notes.txt", "--force"],
     "a csv export over a user's `notes.txt`, with `--force`", "is not a csv export digail wrote"),
    ("export-json-over-bashrc", ["--demos", "src.hdf5", "--export", "json", "--out", "home/.bashrc", "--force"],
     "a json export over a user's `.bashrc`, with `--force`", "is not a json export digail wrote"),
    ("export-robomimic-over-users-hdf5", ["--demos", "src.hdf5", "--export", "robomimic", "--out", "other.hdf5",
                                         "--force"],
     "a robomimic export over a robomimic file digail did not annotate, with `--force`",
     "is not a robomimic export digail wrote"),
    ("export-csv-over-link", ["--demos", "src.hdf5", "--export", "csv", "--out", "link", "--force"],
     "a csv export onto a symbolic link to a user's file, with `--force`", "is a symbolic link"),
    ("export-csv-over-dangling-link", ["--demos", "src.hdf5", "--export", "csv", "--out", "dangling"],
     "a csv export onto a link to nothing, without `--force`", "is a symbolic link"),
    ("export-csv-over-fifo", ["--demos", "src.hdf5", "--export", "csv", "--out", "fifo", "--force"],
     "a csv export onto a FIFO, with `--force`", "is a FIFO"),
    # a socket stands for the devices: a probe must never aim at a real device (as root, a regression would replace
    # /dev/null with a file)
    ("export-csv-over-socket", ["--demos", "src.hdf5", "--export", "csv", "--out", "sock", "--force"],
     "a csv export onto a Unix socket (as onto a device), with `--force`", "is a socket"),
    ("export-csv-to-folder", ["--demos", "src.hdf5", "--export", "csv", "--out", "sub"],
     "a csv export to an existing folder", "is a folder, but --export csv writes a file"),
    ("export-csv-to-folder-force", ["--demos", "src.hdf5", "--export", "csv", "--out", "sub", "--force"],
     "a csv export to an existing folder, with `--force`", "is a folder, but --export csv writes a file"),
    ("export-lerobot-over-file", ["--demos", "lr", "--export", "lerobot", "--out", "notes.txt", "--force"],
     "a LeRobot export over a user's file, with `--force`", "is a file, but --export lerobot writes a folder"),
    ("export-lerobot-over-users-folder", ["--demos", "lr", "--export", "lerobot", "--out", "sub", "--force"],
     "a LeRobot export over a folder of the user's, with `--force`", "is not a folder digail made"),
    ("export-names-dot", ["--demos", "src.hdf5", "--export", "robomimic", "--names", ".", "..", "--out", "x.hdf5"],
     "`--names . ..` for a robomimic export", "neither '.' nor '..'"),
    ("export-csv-new", ["--demos", "src.hdf5", "--export", "csv", "--out", "seg.csv"], "a csv export to a new file",
     None),
    ("export-lerobot-new", ["--demos", "lr", "--export", "lerobot", "--out", "annotated"],
     "a LeRobot export to a new folder", None),
]:
    probe(_pid, f"`digail segment`: {_what}", _expect)(segment(*_argv))


@probe("export-device-check", "the export check of `--out /dev/null --force` (the check alone, which writes nothing)",
       "is a character device")
def _device(tmp: Path) -> None:
    from digail.data.annotations import check_export_target

    check_export_target("csv", Path("/dev/null"), force=True)


def _setup_targets(tmp: Path) -> None:
    (tmp / "link").symlink_to(tmp / "notes.txt")
    (tmp / "dangling").symlink_to(tmp / "nowhere")
    os.mkfifo(tmp / "fifo")
    with socket.socket(socket.AF_UNIX) as sock:  # the file stays once the socket is closed
        sock.bind(str(tmp / "sock"))
    (tmp / "home").mkdir()
    (tmp / "home" / ".bashrc").write_text("export PATH=$PATH\n")
    robomimic(tmp / "other.hdf5")


for _pid, _fmt, _src, _out in [("export-csv-again", "csv", "src.hdf5", "seg.csv"),
                               ("export-json-again", "json", "src.hdf5", "seg.json"),
                               ("export-robomimic-again", "robomimic", "src.hdf5", "annotated.hdf5"),
                               ("export-lerobot-again", "lerobot", "lr", "annotated")]:
    def _again(tmp: Path, fmt: str = _fmt, src: str = _src, out: str = _out) -> None:
        cli(tmp, "segment", "vae", "--demos", src, "--export", fmt, "--out", out)
        cli(tmp, "segment", "vae", "--demos", src, "--export", fmt, "--out", out, "--force")

    probe(_pid, f"`digail segment`: a {_fmt} export over digail's own earlier one, with `--force`", None)(_again)


def _deep_config(tmp: Path) -> None:
    (tmp / "deep").mkdir()
    (tmp / "deep" / "config.json").write_text(DEEP)


probe("export-lerobot-over-deep-config", "`digail segment`: a LeRobot export over a folder whose config.json nests "
      "lists 100,000 deep, with `--force`", "is not a folder digail made", setup=_deep_config)(
    segment("--demos", "lr", "--export", "lerobot", "--out", "deep", "--force"))


def _deep_metadata(tmp: Path) -> None:
    shutil.copytree(tmp / "demos", tmp / "deepds")
    (tmp / "deepds" / "data" / "metadata.json").write_text(DEEP)


probe("export-from-deep-minari-metadata", "`digail segment --demos D --export csv` where D's metadata.json nests "
      "lists 100,000 deep", "cannot read deepds/data/metadata.json", setup=_deep_metadata)(
    segment("--demos", "deepds", "--export", "csv", "--out", "seg.csv"))


def _fifo_in_lerobot(tmp: Path) -> None:
    (tmp / "lr" / "videos").mkdir()
    os.mkfifo(tmp / "lr" / "videos" / "cam.mp4")


probe("export-lerobot-source-fifo", "`digail segment`: a LeRobot export of a dataset holding a FIFO "
      "(`videos/cam.mp4`)", "is a FIFO", setup=_fifo_in_lerobot)(
    segment("--demos", "lr", "--export", "lerobot", "--out", "annotated"))
probe("export-lerobot-source-link-out", "`digail segment`: a LeRobot export of a dataset holding a link to a "
      "user's file outside it", "outside the dataset folder",
      setup=lambda tmp: (tmp / "lr" / "meta" / "notes.txt").symlink_to(tmp / "notes.txt"))(
    segment("--demos", "lr", "--export", "lerobot", "--out", "annotated"))


@probe("export-source-removed", "the robomimic source removed between the segmentation and its export",
       "is no longer there")
def _source_removed(tmp: Path) -> None:
    from digail.data.annotations import export_segmentation
    from digail.data.importers import read_demonstrations

    im = read_demonstrations(tmp / "src.hdf5")
    (tmp / "src.hdf5").rename(tmp / "moved.hdf5")
    try:
        export_segmentation("robomimic", tmp / "x.hdf5", im.episode_keys, [np.zeros(len(t), int) for t in im.trajs],
                            ["p", "q"], source=im.source)
    finally:
        (tmp / "moved.hdf5").rename(tmp / "src.hdf5")


# ------------------------------------------------------------------------------------------------ observation keys
@probe("keys-other-order", "`digail segment --demos src.hdf5 --obs-keys b a` on a run trained on keys a, b",
       "is not what the run was trained on")
def _keys_order(tmp: Path) -> None:
    cli(tmp, "segment", "vae", "--demos", "src.hdf5", "--obs-keys", "b", "a")


@probe("keys-dataset-other-order", "`digail segment --demos D` where D was imported with keys b, a and the run "
       "trained on a, b", "was imported with observation keys b, a")
def _keys_dataset(tmp: Path) -> None:
    cli(tmp, "import", "src.hdf5", "--obs-keys", "b", "a", "--out", "ba")
    try:
        cli(tmp, "segment", "vae", "--demos", "ba")
    finally:
        shutil.rmtree(tmp / "ba")


@probe("keys-same-order", "`digail segment --demos src.hdf5 --obs-keys a b` on a run trained on keys a, b", None)
def _keys_same(tmp: Path) -> None:
    cli(tmp, "segment", "vae", "--demos", "src.hdf5", "--obs-keys", "a", "b")


# ------------------------------------------------------------------------------------------------ reading
def _edit_robomimic(edit: Callable[[h5py.File], None], **kw: object) -> Callable[[Path], None]:
    return lambda path: robomimic(path, edit=edit, **kw)  # type: ignore[arg-type]


def _replace(name: str, value: object, **opts: object) -> Callable[[h5py.File], None]:
    def edit(f: h5py.File) -> None:
        if name in f:
            del f[name]
        if isinstance(value, h5py.SoftLink | h5py.ExternalLink):
            f[name] = value
        elif isinstance(value, tuple):  # declared (shape, chunks), never written
            f.create_dataset(name, shape=value[0], dtype="f4", chunks=value[1])
        elif value is not None:
            f.create_dataset(name, data=value, **opts)

    return edit


def _rename_bytes(old: str, new: bytes) -> Callable[[h5py.File], None]:
    def edit(f: h5py.File) -> None:
        f.move(old, "tmp-name")
        f.id.links.move(b"tmp-name", f.id, new)

    return edit


def _external_storage(f: h5py.File) -> None:
    raw = Path(f.filename).with_name("raw.bin")
    raw.write_bytes(np.zeros((12, 2), np.float32).tobytes())
    del f["data/demo_1/obs/a"]
    f.create_dataset("data/demo_1/obs/a", shape=(12, 2), dtype="f4", external=[(str(raw), 0, 96)])


def _flipped(path: Path) -> None:
    robomimic(path)
    data = bytearray(path.read_bytes())
    # the header of data/demo_1's object: a byte-flipped B-tree / symbol table that h5py trips over while reading
    at = data.index(b"TREE", data.index(b"TREE") + 1)
    data[at:at + 4] = b"EERT"
    path.write_bytes(bytes(data))


def _d4rl(path: Path, observations: object) -> None:
    """A flat D4RL file of 12 steps whose `observations` is `observations` (a link)."""
    with h5py.File(path, "w") as f:
        f["actions"] = np.zeros((12, ACT_DIM), np.float32)
        f["terminals"] = np.eye(12, dtype=bool)[-1]
        f["observations"] = observations


STR = h5py.string_dtype()
READ_PROBES: list[tuple[str, str, Callable[[Path], object], str | None]] = [
    # id, what, how the source is made (src.hdf5 or a folder), expected phrase (None: imported)
    ("rm-second-no-actions", "a robomimic file whose second demonstration lacks `actions`",
     _edit_robomimic(_replace("data/demo_1/actions", None)), "data/demo_1 lacks actions"),
    ("rm-second-no-obs", "a robomimic file whose second demonstration lacks `obs`",
     _edit_robomimic(_replace("data/demo_1/obs", None)), "data/demo_1 lacks obs"),
    ("rm-second-obs-array", "a robomimic file whose second demonstration's `obs` is an array",
     _edit_robomimic(_replace("data/demo_1/obs", np.zeros(3))), "data/demo_1 has the wrong kind of obs"),
    ("rm-zero-length", "a robomimic file with a demonstration of zero steps",
     _edit_robomimic(lambda f: [_replace(f"data/demo_1/{k}", np.zeros((0,) + f[f"data/demo_0/{k}"].shape[1:], "f4"))(f)
                                for k in ("actions", "rewards", "obs/a", "obs/b", "next_obs/a", "next_obs/b")]), None),
    ("rm-all-zero-length", "a robomimic file whose demonstrations all have zero steps",
     lambda p: robomimic(p, steps=0), "holds no demonstration with at least one step"),
    ("rm-demo-dataset", "a robomimic file whose `data/demo_1` is an array, not a group",
     _edit_robomimic(_replace("data/demo_1", np.zeros(3))), "data/demo_1 is an array"),
    ("rm-non-utf8-demo", "a robomimic demonstration named with the byte 0xff",
     _edit_robomimic(_rename_bytes("data/demo_1", b"data/demo_\xff")), "which is not UTF-8"),
    ("rm-non-utf8-key", "a robomimic observation key named with the byte 0xff",
     _edit_robomimic(_rename_bytes("data/demo_0/obs/b", b"data/demo_0/obs/b\xff")), "which is not UTF-8"),
    ("rm-string-obs", "robomimic observations as strings",
     _edit_robomimic(_replace("data/demo_1/obs/a", np.array([["1.5", "2"]] * 12, dtype=object), dtype=STR)),
     "it must be a numeric array"),
    ("rm-numeric-strings", "robomimic observations as fixed-length byte strings of numbers",
     _edit_robomimic(_replace("data/demo_1/obs/b", np.array([[b"1.5"]] * 12))), "it must be a numeric array"),
    ("rm-structured-obs", "robomimic observations as a structured array",
     _edit_robomimic(_replace("data/demo_1/obs/b", np.zeros(12, dtype=[("x", "f4")]))), "it must be a numeric array"),
    ("rm-complex-obs", "complex robomimic observations",
     _edit_robomimic(_replace("data/demo_2/obs/a", np.ones((12, 2)) * 1j)), "complex values in 'a'"),
    ("rm-complex-actions", "complex robomimic actions",
     _edit_robomimic(_replace("data/demo_0/actions", np.ones((12, ACT_DIM)) * 1j)), "complex values in 'actions'"),
    ("rm-scalar-obs", "a robomimic observation key holding a single number",
     _edit_robomimic(_replace("data/demo_1/obs/a", np.float32(1))), "as a single number"),
    ("rm-flipped-bytes", "a robomimic file with flipped bytes in a group's index", _flipped, "the file is damaged"),
    ("rm-dangling-link", "a robomimic demonstration that is a soft link to nothing",
     _edit_robomimic(_replace("data/demo_1", h5py.SoftLink("/data/nowhere"))), "has a soft link at 'data/demo_1'"),
    ("rm-cyclic-link", "a robomimic observation that is a soft link to itself",
     _edit_robomimic(_replace("data/demo_1/obs/a", h5py.SoftLink("/data/demo_1/obs/a"))), "has a soft link"),
    ("rm-external-link", "a robomimic observation that is an external link to another file",
     _edit_robomimic(_replace("data/demo_1/obs/a", h5py.ExternalLink("other.hdf5", "/x"))), "an external link"),
    ("rm-external-storage", "a robomimic observation whose data is stored in a raw file beside it",
     _edit_robomimic(_external_storage), "stores 'a' in another file"),
    ("rm-declares-2e8", "a 12 KB robomimic file declaring 2 x 10^8 rows of an observation (never written)",
     _edit_robomimic(_replace("data/demo_1/obs/a", ((2 * 10**8, 2), (4096, 2)))), "writes only part of it"),
    ("rm-declares-1e12", "a robomimic file declaring 10^12 rows of an observation",
     _edit_robomimic(_replace("data/demo_1/obs/a", ((10**12, 2), (4096, 2)))), "of memory available"),
    ("rm-fifo", "a FIFO named src.hdf5", lambda p: os.mkfifo(p), "is a FIFO"),
    ("rm-d4rl-external-link", "a flat D4RL HDF5 file whose `observations` is an external link to another file",
     lambda p: _d4rl(p, h5py.ExternalLink("other.hdf5", "/observations")), "an external link"),
    ("rm-d4rl-soft-link", "a flat D4RL HDF5 file whose `observations` is a soft link to its `actions`",
     lambda p: _d4rl(p, h5py.SoftLink("/actions")), "has a soft link at 'observations'"),
    ("rm-npz-fifo", "a FIFO named demos.npz", lambda p: os.mkfifo(p.with_suffix(".npz")), "is a FIFO"),
    ("rm-good", "a good robomimic file", robomimic, None),
]


def _lr_json(folder: Path, nested: str) -> None:
    lerobot(folder)
    (folder / "meta" / "info.json").write_text(nested)


def _lr_extra(folder: Path, how: Callable[[Path], None]) -> None:
    lerobot(folder)
    how(folder / "data" / "chunk-000" / "file-001.parquet")


DEEP = "[" * 100_000 + "]" * 100_000
READ_PROBES += [
    ("lr-info-nested", "a LeRobot `meta/info.json` of lists nested 100,000 deep", lambda p: _lr_json(p, DEEP),
     "nests its JSON deeper"),
    ("lr-info-list", "a LeRobot `meta/info.json` holding a list", lambda p: _lr_json(p, "[1]"),
     "has no 'features' table"),
    ("lr-string-state", "a LeRobot `observation.state` column of strings",
     lambda p: lerobot(p, state=pa.array([["x", "y", "z"]] * 30)), "which is not numeric"),
    ("lr-numeric-strings", "a LeRobot `observation.state` column of numbers written as strings",
     lambda p: lerobot(p, state=pa.array([["1", "2", "3"]] * 30)), "which is not numeric"),
    ("lr-zero-rows", "a LeRobot dataset whose Parquet file has no rows", lambda p: lerobot(p, rows=0),
     "holds no frames"),
    ("lr-ragged", "LeRobot `observation.state` rows of 2 and 4 values (6 in all, as two rows of 3)",
     lambda p: lerobot(p, state=pa.array([[1.0, 2.0], [3.0, 4.0, 5.0, 6.0]] * 15, pa.list_(pa.float32()))),
     "rows of different lengths"),
    ("lr-null-state", "a LeRobot `observation.state` with an empty (null) row",
     lambda p: lerobot(p, state=pa.array([None] + [[1.0, 2.0, 3.0]] * 29, pa.list_(pa.float32()))),
     "empty (null) value in"),
    ("lr-fifo-parquet", "a FIFO named `data/chunk-000/file-001.parquet`", lambda p: _lr_extra(p, os.mkfifo),
     "is a FIFO"),
    ("lr-link-out", "a LeRobot frame file that is a link to a file outside the dataset",
     lambda p: _lr_extra(p, lambda f: f.symlink_to(p.parent.parent / "notes.txt")), "outside the dataset folder"),
    ("lr-dangling-link", "a LeRobot frame file that is a link to nothing",
     lambda p: _lr_extra(p, lambda f: f.symlink_to(p / "nowhere.parquet")), "a link to nothing"),
    ("lr-good", "a good LeRobot dataset", lerobot, None),
]


def _imitation(folder: Path, state: object = None, text: str | None = None) -> None:
    shutil.copytree(IMITATION_DIR, folder)
    if state is not None:
        (folder / "state.json").write_text(json.dumps(state))
    if text is not None:
        (folder / "state.json").write_text(text)


def _imitation_ragged(folder: Path) -> None:
    """The fixture folder with the first trajectory's second observation one value short."""
    _imitation(folder)
    arrow = folder / "data-00000-of-00001.arrow"
    with pa.OSFile(str(arrow), "rb") as source:  # read into memory: the file is written again below
        table = pa.ipc.open_stream(source).read_all()
    rows = table.column("obs").to_pylist()
    rows[0][1] = rows[0][1][:-1]
    table = table.set_column(0, table.schema.field("obs"), pa.array(rows, table.schema.field("obs").type))
    with pa.OSFile(str(arrow.with_suffix(".new")), "wb") as sink, pa.ipc.new_stream(sink, table.schema) as writer:
        writer.write_table(table)
    arrow.with_suffix(".new").replace(arrow)


READ_PROBES += [
    ("im-ragged-obs", "an imitation trajectory whose observations are rows of different lengths", _imitation_ragged,
     "'obs' rows of different lengths"),
    ("im-state-parent", "an imitation `state.json` naming `../secret.arrow` (a good Arrow file beside the folder)",
     lambda p: (_imitation(p, {"_data_files": [{"filename": "../secret.arrow"}]}),
                shutil.copy(IMITATION_DIR / "data-00000-of-00001.arrow", p.parent / "secret.arrow")),
     "which is not a file inside"),
    ("im-state-absolute", "an imitation `state.json` naming `/etc/passwd`",
     lambda p: _imitation(p, {"_data_files": [{"filename": "/etc/passwd"}]}), "which is not a file inside"),
    ("im-state-link-out", "an imitation data file that is a link to a file outside the folder",
     lambda p: (_imitation(p), (p / "data-00000-of-00001.arrow").unlink(),
                (p / "data-00000-of-00001.arrow").symlink_to(p.parent.parent / "notes.txt")),
     "outside the dataset folder"),
    ("im-state-nested", "an imitation `state.json` nested 100,000 deep", lambda p: _imitation(p, text=DEEP),
     "nests its JSON deeper"),
    ("im-state-number-name", "an imitation `state.json` naming a file by a number",
     lambda p: _imitation(p, {"_data_files": [{"filename": 7}]}), "not text"),
    ("im-fifo-arrow", "a FIFO in place of an imitation data file",
     lambda p: (_imitation(p), (p / "data-00000-of-00001.arrow").unlink(),
                os.mkfifo(p / "data-00000-of-00001.arrow")), "is a FIFO"),
    ("im-good", "a good imitation datasets folder", _imitation, None),
]

for _pid, _what, _make, _expect in READ_PROBES:
    def _make_input(tmp: Path, make: Callable[[Path], object] = _make, pid: str = _pid) -> None:
        (tmp / "input").mkdir()
        make(tmp / "input" / ("src.hdf5" if pid.startswith("rm-") else "ds"))

    def _run_read(tmp: Path, pid: str = _pid) -> None:
        source = "input/ds" if not pid.startswith("rm-") else "input/src.npz" if "npz" in pid else "input/src.hdf5"
        cli(tmp, "import", source, "--out", "out")

    probe(f"read-{_pid}", f"`digail import` {_what}", _expect, setup=_make_input)(_run_read)


# ------------------------------------------------------------------------------------------------ import outputs
def _marked_with_source(tmp: Path) -> None:
    (tmp / "mine").mkdir()
    (tmp / "mine" / ".digail").write_text("\n")
    robomimic(tmp / "mine" / "src.hdf5")


for _pid, _argv, _what, _expect, _setup in [
    ("import-into-source", ["import", "lr", "--out", "lr/imported"], "`digail import lr --out lr/imported`, inside the "
     "LeRobot folder it reads", "is inside the input", None),
    ("import-over-folder-holding-source", ["import", "mine/src.hdf5", "--out", "mine", "--force"],
     "`digail import mine/src.hdf5 --out mine --force`, where mine is a folder digail made", "holds the input",
     _marked_with_source),
]:
    probe(_pid, _what, _expect, setup=_setup)(lambda tmp, a=tuple(_argv): cli(tmp, *a))


# ------------------------------------------------------------------------------------------------ the tests
def _tree(path: Path) -> dict[str, bytes | str]:
    out: dict[str, bytes | str] = {}
    for p in sorted(path.rglob("*")):
        if p.is_symlink():
            out[str(p.relative_to(path))] = "-> " + os.readlink(p)
        elif p.is_file():
            out[str(p.relative_to(path))] = p.read_bytes()
        elif p.is_dir():
            out[str(p.relative_to(path))] = "dir"
        else:
            out[str(p.relative_to(path))] = "special"
    return out


def outcome(p: Probe, tmp: Path, base: Path) -> str | None:
    """The probe's sentence when refused, None when accepted; `tmp` is set up as the probe's folder first."""
    _copy_base(base, tmp)
    _setup_targets(tmp)
    if p.setup is not None:
        p.setup(tmp)
    try:
        p.run(tmp)
    except UserError as exc:
        return " ".join(str(exc).split())
    return None


@pytest.mark.parametrize("p", PROBES, ids=[p.id for p in PROBES])
def test_probe(p: Probe, tmp_path: Path, base: Path) -> None:
    _copy_base(base, tmp_path)
    _setup_targets(tmp_path)
    if p.setup is not None:
        p.setup(tmp_path)
    before = _tree(tmp_path)
    try:
        p.run(tmp_path)
        sentence = None
    except UserError as exc:
        sentence = " ".join(str(exc).split())
    if p.expect is None:
        assert sentence is None, f"{p.id} was refused: {sentence}"
        return
    assert sentence is not None, f"{p.id} was accepted"
    assert p.expect in sentence, sentence
    assert "\n" not in sentence and "Traceback" not in sentence
    after = _tree(tmp_path)
    changed = sorted(k for k in set(before) | set(after) if before.get(k) != after.get(k))
    assert not changed, f"{p.id} was refused but changed {changed}"
    assert not (tmp_path / "out").exists() and not list(tmp_path.glob(".*tmp*")), "a refused probe wrote"


def test_at_least_fifty_probes() -> None:
    assert len(PROBES) >= 50 and len({p.id for p in PROBES}) == len(PROBES)


def test_the_reliability_page_lists_every_probe() -> None:
    """docs/reference/errors.md publishes these probes in its fifth round: one row each, under the same words."""
    page = (ROOT / "docs" / "reference" / "errors.md").read_text()
    section = page.split("## Probes, fifth round", 1)[1].split("\n## ", 1)[0].split("::: digail.errors", 1)[0]
    missing = [p.id for p in PROBES if f"| {p.what.replace('|', chr(92) + '|')} |" not in section]
    assert not missing, f"probes without a row in the reliability page: {missing}"


# ------------------------------------------------------------------------------------------------ beyond the probes
def test_segment_reads_the_keys_in_the_runs_order(base: Path, tmp_path: Path) -> None:
    """A run trained on keys b, a segments `--demos src.hdf5` (whose default order is a, b) in its own order: the
    codes are those of the run's own dataset."""
    _copy_base(base, tmp_path)
    cli(tmp_path, "import", "src.hdf5", "--obs-keys", "b", "a", "--out", "ba")
    cli(tmp_path, "pretrain", "--demos", "ba", "--codes", "2", "--preset", "smoke", "--out", "vba", "--seed", "3")
    codes = {}
    for demos in ("ba", "src.hdf5"):
        cli(tmp_path, "segment", "vba", "--demos", demos)
        with np.load(tmp_path / "vba" / "codes.npz") as f:
            codes[demos] = [f[k] for k in sorted(f.files)]
    assert all(np.array_equal(x, y) for x, y in zip(codes["ba"], codes["src.hdf5"], strict=True))


def test_segmenting_a_digail_lerobot_export_scores_no_oracle(base: Path, tmp_path: Path) -> None:
    """digail's own `subtask_index` column is a segmentation, not ground truth: segmenting the export again reports
    no oracle scores (before, it scored the model against itself)."""
    _copy_base(base, tmp_path)
    cli(tmp_path, "segment", "vae", "--demos", "lr", "--export", "lerobot", "--out", "annotated")
    cli(tmp_path, "segment", "vae", "--demos", "annotated")
    metrics = json.loads((tmp_path / "vae" / "segmentation.json").read_text())
    assert metrics["labels"] is False and "accuracy" not in metrics, metrics


def test_a_fifo_in_a_lerobot_dataset_ends_at_once(tmp_path: Path) -> None:
    """The FIFO that blocked `digail import` for ever, deaf to SIGTERM: refused from its stat, in a fresh process."""
    _lr_extra(tmp_path / "ds", os.mkfifo)
    env = {**os.environ, "MUJOCO_GL": "egl"}
    proc = subprocess.run([sys.executable, "-m", "digail.cli", "import", "ds", "--out", "out"], cwd=tmp_path, env=env,
                          capture_output=True, text=True, timeout=120)
    assert proc.returncode == 2 and "is a FIFO" in proc.stderr, proc.stderr
    assert not (tmp_path / "out").exists()


def test_sigterm_during_an_import_leaves_nothing(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """SIGTERM while the source is read: exit 128 + 15 with one sentence, no dataset and no temporary folder."""
    from digail.data import importers

    robomimic(tmp_path / "src.hdf5")
    real = importers.read_demonstrations

    def read_then_signal(*args: object, **kw: object) -> object:
        imported = real(*args, **kw)  # type: ignore[arg-type]
        os.kill(os.getpid(), signal.SIGTERM)
        return imported

    monkeypatch.setattr(importers, "read_demonstrations", read_then_signal)
    err = io.StringIO()
    old = Path.cwd()
    os.chdir(tmp_path)
    try:
        with contextlib.redirect_stderr(err), contextlib.redirect_stdout(io.StringIO()):
            code = main(["import", "src.hdf5", "--out", "out"])
    finally:
        os.chdir(old)
    assert code == 128 + signal.SIGTERM and "stopped by SIGTERM" in err.getvalue(), err.getvalue()
    assert sorted(p.name for p in tmp_path.iterdir()) == ["src.hdf5"]
