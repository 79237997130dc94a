"""The small data the dataset and export probes work on (tests/test_probes_datasets.py, test_probes_exports.py):
a robomimic file and a LeRobot dataset made by hand, and the base folder a probe starts from: the robomimic source,
its Minari import, a VAE run on it and a user's files, with the links, FIFO and socket an export is aimed at."""

from __future__ import annotations

import contextlib
import io
import json
import os
import socket
from collections.abc import Callable
from pathlib import Path

import h5py
import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq
from probe_kit import cli

from digail.cli import main

OBS_WIDTHS = {"a": 2, "b": 1}
"""the hand-made robomimic file's observation keys and widths (3 in all, as the LeRobot one's observation.state)"""
ACT_DIM = 2


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


def lerobot(folder: Path, episodes: int = 3, frames: int = 10, state: object = None, rows: int | None = None,
            frame_index: np.ndarray | None = None, frame_gap: bool = False) -> Path:
    """A small LeRobot v3.0 dataset: `episodes` episodes of `frames` frames, a 3-wide observation.state; `state`
    replaces that column (a pyarrow array), `rows` keeps only the first rows, `frame_index` replaces the first
    episode's frame numbers and `frame_gap` numbers it 0..4, 6..10 (a frame missing)."""
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
    if frame_gap:
        frame_index = np.concatenate([np.arange(frames // 2), np.arange(frames // 2 + 1, frames + 1)])
    if frame_index is not None:
        numbers = np.tile(np.arange(frames), episodes)
        numbers[:frames] = frame_index
        columns["frame_index"] = pa.array(numbers)
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


def segment(*argv: str) -> Callable[[Path], None]:
    return lambda tmp: cli(tmp, "segment", "vae", *argv)


def targets(tmp: Path) -> None:
    """What the export probes aim at beside the base folder's copy: a link to a user's file, a link to nothing, a
    FIFO, a socket, a home folder with its .bashrc and a robomimic file digail did not annotate."""
    (tmp / "link").symlink_to(tmp / "notes.txt")
    (tmp / "dangling").symlink_to(tmp / "nowhere")
    os.mkfifo(tmp / "fifo")
    with socket.socket(socket.AF_UNIX) as sock:  # the file stays once the socket is closed
        sock.bind(str(tmp / "sock"))
    (tmp / "home").mkdir()
    (tmp / "home" / ".bashrc").write_text("export PATH=$PATH\n")
    robomimic(tmp / "other.hdf5")
