"""Failure-path probes of the data digail reads: imported files (npz, HDF5, D4RL, robomimic, LeRobot,
imitation), replay buffers in checkpoints, the observation keys a run was trained on, shipped datasets damaged,
and robosuite-made robomimic files. The probes, with what each gets, are the reliability page's section of the same
name (docs/reference/errors.md).
"""

from __future__ import annotations

import contextlib
import io
import json
import os
import pickle
import shutil
import signal
import subprocess
import sys
import zipfile
from collections.abc import Callable
from pathlib import Path

import h5py
import numpy as np
import pyarrow as pa
import pytest
import torch
from probe_data import ACT_DIM, lerobot, make_base, robomimic, targets
from probe_kit import (
    CW_DEMOS,
    MW,
    MW_DEMOS,
    ROOT,
    Probe,
    ProbeTable,
    assert_published,
    check_probe,
    cli,
    copy_base,
    plant,
    refusal,
)

from digail.cli import main
from digail.errors import UserError

ROBOSUITE = ROOT / "tests" / "data" / "robosuite"


IMITATION_DIR = ROOT / "tests" / "data" / "formats" / "imitation_dataset"

PROBES = ProbeTable()
probe = PROBES.add


def probe_on_base(pid: str, what: str, expect: str | None, setup: Callable[[Path], object] | None = None
                  ) -> Callable[[Callable[[Path], object]], Callable[[Path], object]]:
    """A probe whose folder starts as a copy of the base folder (`probe_data.make_base`) with the targets an export
    is aimed at (`probe_data.targets`), then what its own `setup` makes."""
    def prepare(tmp: Path) -> None:
        targets(tmp)
        if setup is not None:
            setup(tmp)

    return PROBES.add(pid, what, expect, prepare, on_base=True)


@pytest.fixture(scope="module")
def base(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return make_base(tmp_path_factory.mktemp("base"))


# ------------------------------------------------------------------------------------------------ imported files
def _good_arrays(n: int = 20) -> dict[str, np.ndarray]:
    rng = np.random.default_rng(2)
    return {"observations": rng.normal(size=(n, 3)).astype(np.float32),
            "actions": rng.normal(size=(n, 1)).astype(np.float32), "episode_ends": np.array([n // 2, n])}


def _d4rl_arrays(n: int = 20) -> dict[str, np.ndarray]:
    good = _good_arrays(n)
    terminals = np.zeros(n, bool)
    terminals[n // 2 - 1] = terminals[-1] = True
    return {"observations": good["observations"], "actions": good["actions"], "terminals": terminals}


def _header_npz(path: Path, key: str, shape: tuple[int, ...], fortran: bool = False) -> None:
    arrays = _good_arrays()
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
        np.savez(path, **{**_good_arrays(), **changes})

    return make


def _h5_layout(**changes: object) -> Callable[[Path], None]:
    def make(path: Path) -> None:
        with h5py.File(path, "w") as f:
            for key, value in {**_d4rl_arrays(), **changes}.items():
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
    np.savez_compressed(path, **_good_arrays())
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
    ("npz-complex-obs", "d.npz", "complex observations", _npz(observations=_good_arrays()["observations"] + 1j),
     "complex values in 'observations'"),
    ("npz-complex-acts", "d.npz", "complex actions", _npz(actions=_good_arrays()["actions"] * 1j),
     "complex values in 'actions'"),
    ("npz-1e300-obs", "d.npz", "float64 observations of 1e300 (finite, beyond float32)",
     _npz(observations=_good_arrays()["observations"].astype(np.float64) * 1e300), "beyond float32's range"),
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
    ("h5-half", "d.hdf5", "an HDF5 file cut in half", _cut(_h5_layout(), 0.5), "the file is damaged"),
    ("h5-terminals-2d", "d.hdf5", "D4RL terminals of shape (20, 2)", _h5_layout(terminals=np.zeros((20, 2), bool)),
     "'terminals' of shape (20, 2)"),
    ("h5-timeouts-2d", "d.hdf5", "D4RL timeouts of shape (20, 1)", _h5_layout(timeouts=np.zeros((20, 1), bool)),
     "'timeouts' of shape (20, 1)"),
    ("h5-terminals-half", "d.hdf5", "terminals of 0.5", _h5_layout(terminals=np.full(20, 0.5)),
     "values other than True/False"),
    ("h5-obs-group", "d.hdf5", "observations as an HDF5 group", _h5_layout(observations={}),
     "has no 'observations' array"),
    ("h5-vlen-strings", "d.hdf5", "observations as variable-length strings",
     _h5_layout(observations=np.array(["a"] * 20, dtype=h5py.string_dtype())), "it must be a numeric array"),
    ("h5-huge-chunked", "d.hdf5", "a chunked dataset declaring 10^12 x 3 float32",
     _h5_layout(observations=((10**12, 3), (1024, 3))), "of memory available"),
    ("h5-huge-contiguous", "d.hdf5", "a contiguous dataset declaring 10^11 x 3 float32, never written",
     _h5_layout(observations=((10**11, 3), None)), "the file is damaged or cut short"),
    ("h5-complex", "d.hdf5", "complex observations in HDF5",
     _h5_layout(observations=_d4rl_arrays()["observations"] * 1j),
     "complex values in 'observations'"),
    ("h5-1e300-next", "d.hdf5", "next_observations of 1e300",
     _h5_layout(next_observations=np.full((20, 3), 1e300)), "beyond float32's range"),
    ("h5-no-flags", "d.hdf5", "neither terminals nor timeouts", _h5_layout(terminals=None, timeouts=None),
     "none of the layouts"),
    ("h5-good", "d.h5", "a good D4RL file named .h5", _h5_layout(), None),
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


# ------------------------------------------------------------------------------------------------ observation keys
@probe_on_base("keys-other-order", "`digail segment --demos src.hdf5 --obs-keys b a` on a run trained on keys a, b",
       "is not what the run was trained on")
def _keys_order(tmp: Path) -> None:
    cli(tmp, "segment", "vae", "--demos", "src.hdf5", "--obs-keys", "b", "a")


@probe_on_base("keys-dataset-other-order", "`digail segment --demos D` where D was imported with keys b, a and the run "
       "trained on a, b", "was imported with observation keys b, a")
def _keys_dataset(tmp: Path) -> None:
    cli(tmp, "import", "src.hdf5", "--obs-keys", "b", "a", "--out", "ba")
    try:
        cli(tmp, "segment", "vae", "--demos", "ba")
    finally:
        shutil.rmtree(tmp / "ba")


@probe_on_base("keys-same-order", "`digail segment --demos src.hdf5 --obs-keys a b` on a run trained on keys a, b",
               None)
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
    ("lr-frame-gap", "a LeRobot episode whose `frame_index` skips a frame (0..4, 6..10)",
     lambda p: lerobot(p, frame_gap=True), "skips frame_index 5"),
    ("lr-frame-twice", "a LeRobot episode whose `frame_index` holds a frame twice",
     lambda p: lerobot(p, frame_index=np.array([0, 1, 2, 2, 4, 5, 6, 7, 8, 9])), "has frame_index 2 twice"),
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

def _zero_wide(f: h5py.File) -> None:
    """Every demonstration's observations one key of 0 values per step (robomimic keys a and b removed)."""
    for demo in f["data"].values():
        for group in ("obs", "next_obs"):
            for key in list(demo[group]):
                del demo[f"{group}/{key}"]
            demo[f"{group}/empty"] = np.zeros((len(demo["actions"]), 0), np.float32)


def _signals(value: float) -> Callable[[h5py.File], None]:
    """Sub-task signals `grasp` in every demonstration, 0 then 1 at step 6, with `value` at step 2."""
    def edit(f: h5py.File) -> None:
        for demo in f["data"].values():
            signal = np.zeros(len(demo["actions"]), np.float64)
            signal[6:] = 1
            signal[2] = value
            demo["datagen_info/subtask_term_signals/grasp"] = signal

    return edit


READ_PROBES += [
    ("rm-obs-zero-wide", "a robomimic file whose only observation key holds 0 values per step",
     _edit_robomimic(_zero_wide), "0 values wide"),
    ("rm-signal-nan", "a robomimic file with NaN in a sub-task signal", _edit_robomimic(_signals(float("nan"))),
     "NaN or inf in datagen_info/subtask_term_signals/grasp"),
    ("rm-signal-ok", "a robomimic file with a sub-task signal of 0 and 1", _edit_robomimic(_signals(0.0)), None),
    ("rm-actions-scalar", "a robomimic file whose second demonstration's `actions` is a single number",
     _edit_robomimic(_replace("data/demo_1/actions", 0.5)), "has 'actions' as a single number"),
]


for _pid, _what, _make, _expect in READ_PROBES:
    def _make_input(tmp: Path, make: Callable[[Path], object] = _make, pid: str = _pid) -> None:
        (tmp / "input").mkdir()
        make(tmp / "input" / ("src.hdf5" if pid.startswith("rm-") else "ds"))

    def _run_read(tmp: Path, pid: str = _pid) -> None:
        source = "input/ds" if not pid.startswith("rm-") else "input/src.npz" if "npz" in pid else "input/src.hdf5"
        cli(tmp, "import", source, "--out", "out")

    probe_on_base(f"read-{_pid}", f"`digail import` {_what}", _expect, setup=_make_input)(_run_read)


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
    probe_on_base(_pid, _what, _expect, setup=_setup)(lambda tmp, a=tuple(_argv): cli(tmp, *a))


# ------------------------------------------------------------------------------------------------ Meta-World datasets
def _mw_copy(tmp: Path) -> Path:
    from digail.data.minari_io import resolve_dataset

    src = resolve_dataset(MW_DEMOS)
    shutil.copytree(src, tmp / "ds")
    return tmp / "ds"


def _damaged(edit: Callable[[Path], None], *argv: str) -> Callable[[Path], None]:
    def run(tmp: Path) -> None:
        ds = _mw_copy(tmp)
        edit(ds)
        cli(tmp, *(a.replace("DS", "ds") for a in argv))

    return run


def _mw_h5(ds: Path, fn: Callable[[h5py.File], None]) -> None:
    with h5py.File(ds / "data" / "main_data.hdf5", "r+") as f:
        fn(f)


def _set_obs(f: h5py.File, value: float, row: int = 3) -> None:
    obs = f["episode_0/observations"][...].astype(np.float64)  # as a float64 env records them
    obs[row, 0] = value
    del f["episode_0/observations"]
    f["episode_0/observations"] = obs


def _meta(ds: Path, change: Callable[[dict], object]) -> None:
    path = ds / "data" / "metadata.json"
    meta = json.loads(path.read_text())
    change(meta)
    path.write_text(json.dumps(meta))


PRETRAIN = ("pretrain", "--demos", "DS", "--codes", "2", "--preset", "smoke", "--vae.steps", "2", "--vae.init-steps",
            "0", "--out", "vae")
for _pid, _what, _edit, _argv, _expect in [
    ("mwds-obs-nan", "an observation NaN", lambda ds: _mw_h5(ds, lambda f: _set_obs(f, float("nan"))), PRETRAIN,
     "NaN or inf"),
    ("mwds-obs-inf", "an observation inf", lambda ds: _mw_h5(ds, lambda f: _set_obs(f, float("inf"))), PRETRAIN,
     "NaN or inf"),
    ("mwds-obs-1e300", "a float64 observation of 1e300", lambda ds: _mw_h5(ds, lambda f: _set_obs(f, 1e300)), PRETRAIN,
     "float32"),
    ("mwds-actions-cut", "episode 0's actions one short",
     lambda ds: _mw_h5(ds, lambda f: (f.__setitem__("a", f["episode_0/actions"][:-1]),
                                   f.__delitem__("episode_0/actions"), f.move("a", "episode_0/actions"))),
     PRETRAIN, "episode 0"),
    ("mwds-no-episodes", "its episodes removed",
     lambda ds: _mw_h5(ds, lambda f: [f.__delitem__(k) for k in list(f.keys())]), PRETRAIN, "ds"),
    ("mwds-hdf5-truncated", "main_data.hdf5 cut in half",
     lambda ds: (ds / "data" / "main_data.hdf5").write_bytes((ds / "data" / "main_data.hdf5").read_bytes()[:50000]),
     PRETRAIN, "ds"),
    ("mwds-metadata-list", "metadata.json a JSON list", lambda ds: (ds / "data" / "metadata.json").write_text("[]"),
     PRETRAIN, "metadata.json"),
    ("mwds-env-spec-other-task", "env_spec naming metaworld/hammer-v3 and `--env` pick-place (39-d either way: "
     "trained, with a note)",
     lambda ds: _meta(ds, lambda m: m.__setitem__("env_spec", m["env_spec"].replace("pick-place", "hammer"))),
     ("train", "--method", "gail", "--demos", "DS", "--env", MW, "--preset", "smoke", "--train.iterations", "1",
      "--out", "run-new"), None),
    ("mwds-env-spec-garbage", "env_spec that is not JSON", lambda ds: _meta(ds, lambda m: m.__setitem__(
        "env_spec", "{not json")), PRETRAIN, "cannot read the Minari dataset"),
    ("mwds-env-spec-module", "env_spec naming an entry point `evil6:Env` (evil6.py beside it)",
     lambda ds: (_meta(ds, lambda m: m.__setitem__("env_spec", m["env_spec"].replace(
         "metaworld/pick-place-v3", "Evil6-v0").replace("digail.envs.metaworld:MetaWorldEnv", "evil6:Env"))),
                 plant(ds.parent, "evil6")),
     ("train", "--method", "gail", "--demos", "DS", "--preset", "smoke", "--train.iterations", "1", "--out",
      "run-new"), "pass --env evil6:Evil6-v0 to allow it"),
    ("mwds-labels-partial", "subtask labels removed from episode 1 only",
     lambda ds: _mw_h5(ds, lambda f: f.__delitem__("episode_1/infos/subtask") if "episode_1/infos/subtask" in f else
                    None), PRETRAIN, "labels"),
]:
    probe(_pid, f"`digail {_argv[0]}` on a copy of the shipped Meta-World pick-place dataset with {_what}", _expect)(
        _damaged(_edit, *_argv))

probe("mwds-demos-episodes-too-many", f"`digail pretrain --demos {MW_DEMOS} --demos-episodes 1000`", "1000")(
    lambda tmp: cli(tmp, "pretrain", "--demos", MW_DEMOS, "--codes", "2", "--demos-episodes", "1000", "--out", "vae"))
probe("mwds-demos-subsample-0", f"`digail pretrain --demos {MW_DEMOS} --demos-subsample 0`",
      "--demos-subsample must be at least 1")(
    lambda tmp: cli(tmp, "pretrain", "--demos", MW_DEMOS, "--codes", "2", "--demos-subsample", "0", "--out", "vae"))
probe("mwds-codes-0", f"`digail pretrain --demos {MW_DEMOS} --codes 0`", "--codes must be between 1 and 256")(
    lambda tmp: cli(tmp, "pretrain", "--demos", MW_DEMOS, "--codes", "0", "--out", "vae"))
probe("mwds-id-typo", "`digail pretrain --demos digail/metaworld-pick-plac/expert-v0`", "no Minari dataset")(
    lambda tmp: cli(tmp, "pretrain", "--demos", "digail/metaworld-pick-plac/expert-v0", "--codes", "2", "--out",
                    "vae"))

# ------------------------------------------------------------------------------------------------ robosuite files
def _rs_copy(tmp: Path, name: str = "stack") -> Path:
    shutil.copy(ROBOSUITE / f"{name}.hdf5", tmp / "rs.hdf5")
    return tmp / "rs.hdf5"


def _rs(edit: Callable[[h5py.File], object], *argv: str, name: str = "stack") -> Callable[[Path], None]:
    def run(tmp: Path) -> None:
        path = _rs_copy(tmp, name)
        with h5py.File(path, "r+") as f:
            edit(f)
        cli(tmp, *argv)

    return run


def _rs_replace(f: h5py.File, key: str, value: np.ndarray) -> None:
    del f[key]
    f[key] = value


IMPORT = ("import", "rs.hdf5", "--out", "out")
for _pid, _what, _edit, _argv, _expect in [
    ("rs-ok", "nothing changed", lambda f: None, IMPORT, None),
    ("rs-actions-missing-in-demo-3", "demo_3's actions removed", lambda f: f.__delitem__("data/demo_3/actions"),
     IMPORT, "demo_3"),
    ("rs-obs-key-missing-in-demo-5", "demo_5's `object` observation removed",
     lambda f: f.__delitem__("data/demo_5/obs/object"), IMPORT, "demo_5"),
    ("rs-actions-wrong-width", "demo_0's actions 3 wide instead of 7",
     lambda f: _rs_replace(f, "data/demo_0/actions", f["data/demo_0/actions"][:, :3]), IMPORT, "actions of shape"),
    ("rs-actions-short", "demo_0 one action short",
     lambda f: _rs_replace(f, "data/demo_0/actions", f["data/demo_0/actions"][:-2]), IMPORT, "demo_0"),
    ("rs-obs-nan", "a NaN in demo_0's eef position",
     lambda f: _rs_replace(f, "data/demo_0/obs/robot0_eef_pos",
                        np.where(np.arange(len(f["data/demo_0/obs/robot0_eef_pos"]))[:, None] == 2, np.nan,
                                 f["data/demo_0/obs/robot0_eef_pos"][...])), IMPORT, "NaN or inf"),
    ("rs-obs-1e300", "demo_0's eef position float64 with a 1e300",
     lambda f: _rs_replace(f, "data/demo_0/obs/robot0_eef_pos",
                        np.where(np.arange(len(f["data/demo_0/obs/robot0_eef_pos"]))[:, None] == 2, 1e300,
                                 f["data/demo_0/obs/robot0_eef_pos"][...].astype(np.float64))), IMPORT, "float32"),
    ("rs-obs-complex", "demo_0's object observation complex",
     lambda f: _rs_replace(f, "data/demo_0/obs/object", f["data/demo_0/obs/object"][...].astype(np.complex64)),
     IMPORT, "complex"),
    ("rs-env-args-not-json", "env_args that is not JSON",
     lambda f: f["data"].attrs.__setitem__("env_args", "{not json"), IMPORT, None),
    ("rs-env-args-deep", "env_args nested 100,000 deep",
     lambda f: f["data"].attrs.__setitem__("env_args", "[" * 100000 + "]" * 100000), IMPORT, None),
    ("rs-data-empty", "no demonstrations under data",
     lambda f: [f["data"].__delitem__(k) for k in list(f["data"].keys())], IMPORT, "rs.hdf5"),
    ("rs-demo-zero-length", "demo_0 with zero steps",
     lambda f: [_rs_replace(f, f"data/demo_0/{k}", f[f"data/demo_0/{k}"][:0])
                for k in ("actions", *(f"obs/{o}" for o in f["data/demo_0/obs"]))], IMPORT, None),
    ("rs-mask-names-missing-demo", "a mask naming demo_999",
     lambda f: f.create_dataset("mask/train", data=np.array([b"demo_0", b"demo_999"])), IMPORT, None),
    ("rs-external-link", "demo_0's actions an external link to another file",
     lambda f: (f.__delitem__("data/demo_0/actions"), f.__setitem__("data/demo_0/actions",
                                                                   h5py.ExternalLink("other.hdf5", "/x"))),
     IMPORT, "link"),
    ("rs-obs-keys-unknown", "nothing changed, `--obs-keys nothing_here`", lambda f: None,
     ("import", "rs.hdf5", "--obs-keys", "nothing_here", "--out", "out"), "nothing_here"),
    ("rs-obs-keys-empty", "nothing changed, `--obs-keys ''`", lambda f: None,
     ("import", "rs.hdf5", "--obs-keys", "", "--out", "out"), "obs"),
    ("rs-import-oracle", "the oracle file imported as demonstrations (it holds MimicGen's signals only)",
     lambda f: None, ("import", "rs.oracle.hdf5", "--out", "out"), "rs.oracle.hdf5"),
    ("rs-import-over-source", "nothing changed, `--out rs.hdf5 --force`", lambda f: None,
     ("import", "rs.hdf5", "--out", "rs.hdf5", "--force"), "rs.hdf5"),
    ("rs-import-into-own-folder", "nothing changed, `--out .`", lambda f: None, ("import", "rs.hdf5", "--out", "."),
     "."),
    ("rs-pickplacecan-ok", "nothing changed", lambda f: None, IMPORT, None),
    ("rs-format-d4rl", "nothing changed, `--format d4rl`", lambda f: None,
     ("import", "rs.hdf5", "--format", "d4rl", "--out", "out"), "rs.hdf5"),
    ("rs-pickplacecan-env-mismatch", "PickPlaceCan's file with `--env digail/FetchPickAndPlace-v4`",
     lambda f: None, ("import", "rs.hdf5", "--env", "digail/FetchPickAndPlace-v4", "--out", "out"), "shape"),
]:
    def _rs_probe(tmp: Path, edit: Callable[[h5py.File], object] = _edit, argv: tuple[str, ...] = tuple(_argv),
                  name: str = "pickplacecan" if "pickplacecan" in _pid else "stack") -> None:
        if "rs.oracle.hdf5" in argv:
            shutil.copy(ROBOSUITE / "stack.oracle.hdf5", tmp / "rs.oracle.hdf5")
        _rs(edit, *argv, name=name)(tmp)

    _task = "PickPlaceCan" if "pickplacecan" in _pid else "Stack"
    probe(_pid, f"`digail {' '.join(_argv)}` on a copy of the robosuite-made {_task} file with {_what}",
          _expect)(_rs_probe)



# ---------------------------------------------------------------------------------------- tests beyond the probes
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


def _good_file() -> dict[str, np.ndarray]:
    rng = np.random.default_rng(1)
    return {"observations": rng.normal(size=(20, 3)).astype(np.float32),
            "actions": rng.normal(size=(20, 1)).astype(np.float32), "episode_ends": np.array([10, 20])}


def _truncated(path: Path) -> None:
    np.savez(path, **_good_file())
    data = path.read_bytes()
    path.write_bytes(data[: len(data) // 2])


def _truncated_member(path: Path) -> None:
    """A compressed member cut inside its data, the zip's directory intact."""
    np.savez_compressed(path, **_good_file())
    data = bytearray(path.read_bytes())
    data[60:80] = bytes(20)
    path.write_bytes(bytes(data))


def _h5_file(path: Path, **arrays: object) -> None:
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
    "complex.npz": (lambda p: np.savez(p, **{**_good_file(), "observations": _good_file()["observations"] + 1j}),
                    "complex values in 'observations'"),
    "beyond_float32.npz": (lambda p: np.savez(p, **{**_good_file(), "observations": _good_file()["observations"]
                                                    .astype(np.float64) * 1e300}), "beyond float32's range"),
    "terminals_2d.hdf5": (lambda p: _h5_file(p, observations=np.zeros((20, 3), np.float32),
                                        actions=np.zeros((20, 1), np.float32), terminals=np.zeros((20, 2), bool)),
                          "'terminals' of shape (20, 2)"),
    "huge_chunked.hdf5": (lambda p: _h5_file(p, observations=((10**12, 3), (1024, 3)),
                                        actions=np.zeros((20, 1), np.float32), terminals=np.zeros(20, bool)),
                          "of memory available"),
    "huge_contiguous.hdf5": (lambda p: _h5_file(p, observations=((10**11, 3), None),
                                           actions=np.zeros((20, 1), np.float32), terminals=np.zeros(20, bool)),
                             "the file is damaged or cut short"),
}


@pytest.mark.parametrize("name", list(BAD_FILES))
def test_a_bad_file_is_one_sentence_and_writes_nothing(name, tmp_path, capsys):
    make, phrase = BAD_FILES[name]
    source = tmp_path / name
    make(source)
    out = tmp_path / "out"
    line = refusal(["import", str(source), "--out", str(out)], phrase)
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
    refusal(["pretrain", "--demos", CW_DEMOS, "--preset", "smoke", "--demos-subsample", "100000", "--out",
                 str(out)], "--demos-subsample 100000 is at least as long as every demonstration")
    assert not out.exists()


def test_a_replay_buffer_larger_than_memory_is_refused(tmp_path, capsys):
    out = tmp_path / "run"
    refusal(["train", "--method", "gail", "--demos", CW_DEMOS, "--preset", "smoke", "--train.learner", "sac",
                 "--train.sac.buffer-size", "1000000000000", "--out", str(out)],
            "--train.sac.buffer-size 1000000000000 needs", "of memory is available")
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


def test_segment_reads_the_keys_in_the_runs_order(base: Path, tmp_path: Path) -> None:
    """A run trained on keys b, a segments `--demos src.hdf5` (whose default order is a, b) in its own order: the
    codes are those of the run's own dataset."""
    copy_base(base, tmp_path)
    cli(tmp_path, "import", "src.hdf5", "--obs-keys", "b", "a", "--out", "ba")
    cli(tmp_path, "pretrain", "--demos", "ba", "--codes", "2", "--preset", "smoke", "--out", "vba", "--seed", "3")
    codes = {}
    for demos in ("ba", "src.hdf5"):
        cli(tmp_path, "segment", "vba", "--demos", demos)
        with np.load(tmp_path / "vba" / "codes.npz") as f:
            codes[demos] = [f[k] for k in sorted(f.files)]
    assert all(np.array_equal(x, y) for x, y in zip(codes["ba"], codes["src.hdf5"], strict=True))



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


# ------------------------------------------------------------------------------------------------ the probes
@pytest.mark.parametrize("p", PROBES, ids=[p.id for p in PROBES])
def test_probe(p: Probe, tmp_path: Path, request: pytest.FixtureRequest) -> None:
    check_probe(p, tmp_path, request.getfixturevalue("base") if p.on_base else None)


def test_the_reliability_page_lists_every_probe() -> None:
    assert_published(PROBES, "Probes: datasets and imports")
