"""A segmentation written back where other tools look for sub-task annotations.

Four targets (`EXPORTS`):

- `robomimic`: a copy of the robomimic file the demonstrations came from, with MimicGen's
  `datagen_info/subtask_term_signals/<name>` per demonstration (`digail.data.robomimic.write_subtask_signals`).
- `lerobot`: a copy of the LeRobot dataset with a per-frame `subtask_index` column and `meta/subtasks.parquet`
  (`digail.data.lerobot.write_subtask_index`).
- `csv`, `json`: a plain table of segments, one row per segment: `episode` (the episode's name in its source),
  `start`, `end` (the segment covers steps start .. end - 1), `code`, `name`.

Steps are the demonstration's action steps as digail read them. Where an export goes is checked once, before any
work (`check_export`): never the input, the run folder or its dataset (nor anything inside or holding them), never
a link, a FIFO or a device, and an existing output only with `--force` and only when digail wrote it (a folder
with digail's marker; a file that is an export of the same kind).
"""

from __future__ import annotations

import csv
import io
import json
import os
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from digail.data.input_files import check_tree
from digail.errors import UserError
from digail.fsio import atomic_write_bytes, check_output

EXPORTS = ("robomimic", "lerobot", "csv", "json")
"""where `export_segmentation` writes"""

SOURCE_FORMAT = {"robomimic": "robomimic", "lerobot": "lerobot"}
"""the input layout each annotated-copy export needs"""


def code_names(n_codes: int, names: Sequence[str] | None = None) -> list[str]:
    """One name per code: `names` when given (checked: one per code, distinct, non-empty), else `code_<k>`."""
    if not names:
        return [f"code_{k}" for k in range(n_codes)]
    names = list(names)
    if len(names) != n_codes:
        raise UserError(f"--names gives {len(names)} names for a model of {n_codes} codes; give one name per code.")
    if len(set(names)) != len(names) or any(not n or "/" in n or n in (".", "..") for n in names):
        raise UserError("--names must be distinct, non-empty, without '/' and neither '.' nor '..'; they name HDF5 "
                        "datasets and table rows.")
    return names


def segments(codes: np.ndarray) -> list[tuple[int, int, int]]:
    """The runs of equal codes of one episode as (start, end, code), `end` exclusive."""
    codes = np.asarray(codes).reshape(-1)
    if not len(codes):
        return []
    cuts = np.flatnonzero(np.diff(codes)) + 1
    starts, ends = np.concatenate([[0], cuts]), np.concatenate([cuts, [len(codes)]])
    return [(int(a), int(b), int(codes[a])) for a, b in zip(starts, ends, strict=True)]


def segment_rows(episode_keys: Sequence[str], codes: Sequence[np.ndarray], names: Sequence[str]) -> list[dict[str,
                                                                                                                Any]]:
    """The segments table: one dict per segment with episode, start, end, code, name."""
    return [{"episode": key, "start": a, "end": b, "code": k, "name": names[k]}
            for key, episode_codes in zip(episode_keys, codes, strict=True) for a, b, k in segments(episode_codes)]


def check_export(fmt: str, out: Path | None, source: str | None, source_format: str | None, force: bool, *,
                 protected: Sequence[tuple[str | os.PathLike[str], str]] = ()) -> None:
    """Refuse, before any work, an export that cannot or must not be written: an unknown format, no `--out`, an
    `--out` that `check_export_target` refuses (the source and `protected` are never written), an annotated copy of
    a source that is not of its layout or no longer there.

    Args:
        protected: further (path, what it is) pairs `out` must stay clear of: the run folder, its dataset.
    """
    if fmt not in EXPORTS:
        raise UserError(f"unknown export {fmt!r}; choose one of {', '.join(EXPORTS)}.")
    if out is None:
        raise UserError(f"--export {fmt} needs --out: the file or folder to write.")
    inputs = [(source, "the input")] if source is not None else []
    check_export_target(fmt, out, force, [*inputs, *protected])
    need = SOURCE_FORMAT.get(fmt)
    if need is None:
        return
    if source_format != need or source is None:
        got = f"the {source_format} layout" if source_format else "no imported file"
        raise UserError(f"--export {fmt} annotates a copy of the {need} source the demonstrations were read from, "
                        f"but they come from {got}; pass the {need} source as --demos, or export csv or json.")
    if not Path(source).exists():
        raise UserError(f"the demonstrations were imported from {source}, which is no longer there; pass the {need} "
                        "source as --demos.")
    if fmt == "lerobot":
        check_tree(source)  # what the copy would block on (a FIFO) or bring in from elsewhere (a link out)


def check_export_target(fmt: str, out: Path, force: bool,
                        protected: Sequence[tuple[str | os.PathLike[str], str]] = ()) -> None:
    """Refuse an `--out` that an export must not write, in one sentence: one that is, lies inside or holds a
    `protected` path (the input, the run, its dataset; links resolved); a link (even one to nothing), a FIFO, a
    device or a socket; a folder where a file export goes or a file where the LeRobot folder goes; an existing one
    without `force`, and with it anything but digail's own output (`check_replaceable` for the LeRobot folder, an
    export of the same kind for a file); a place that cannot be written."""
    suffix = {"robomimic": "hdf5"}.get(fmt, fmt)
    writes = ("--export lerobot writes a folder (a copy of the dataset)" if fmt == "lerobot" else
              f"--export {fmt} writes a file")
    check_output(Path(out), "folder" if fmt == "lerobot" else "file", force, protected=protected,
                 ours=lambda path: _digail_export(fmt, path), ours_what=f"a {fmt} export digail wrote",
                 writes=writes, example=f"segments.{suffix}")


_TABLE_HEADS = {"csv": (b"episode,start,end,code,name,reading\n", b"episode,start,end,code,name\n"),
                "json": (b'{\n "names": [',)}
"""how the tables `export_segmentation` writes begin (today's, then those written before the `reading` column):
what tells an earlier export from a user's file"""


def _digail_export(fmt: str, path: Path) -> bool:
    """Whether the regular file `path` is an export of kind `fmt` digail wrote (which `--force` may replace)."""
    if fmt in _TABLE_HEADS:
        try:
            with open(path, "rb") as f:
                start = f.read(max(map(len, _TABLE_HEADS[fmt])))
        except OSError:
            return False
        return any(start.startswith(head) for head in _TABLE_HEADS[fmt])
    import h5py

    from digail.data.robomimic import SIGNALS_PATH, demo_keys

    try:
        if not h5py.is_hdf5(path):
            return False
        with h5py.File(path, "r") as f:
            data = f.get("data")
            if not isinstance(data, h5py.Group):
                return False
            for key in demo_keys(data):
                signals = data.get(f"{key}/{SIGNALS_PATH}", getlink=False)
                if isinstance(signals, h5py.Group) and "digail_signals" in signals.attrs:
                    return True
    except (OSError, RuntimeError, KeyError, ValueError, TypeError):
        return False
    return False


def export_segmentation(fmt: str, out: Path, episode_keys: Sequence[str], codes: Sequence[np.ndarray],
                        names: Sequence[str], *, source: str | None = None, force: bool = False,
                        notes: list[str] | None = None, reading: str = "causal") -> Path:
    """Write the codes of each episode to `out` in `fmt` (see the module docstring); returns `out`. The export
    names the reading its codes are in (`reading`, `digail.algos.decode.READINGS`): the JSON's `reading` key, the
    CSV's `reading` column, the robomimic file's `digail_reading` attribute beside the signals, the LeRobot
    names table's `digail_reading` schema metadata.

    Args:
        fmt: one of `EXPORTS`.
        out: the file (robomimic, csv, json) or folder (lerobot) to write; never the source.
        episode_keys: each episode's name in its source (`Imported.episode_keys`).
        codes: one (T,) array of codes per episode, in the order of `episode_keys`.
        names: one name per code (`code_names`).
        source: the robomimic file or LeRobot folder to copy (for those two exports).
        force: replace an existing `out`.
        notes: where an export that had to choose something (robomimic: the sub-tasks' order and boundaries for
            MimicGen) appends one line saying what.
    """
    out = Path(out)
    check_export_target(fmt, out, force, [(source, "the input")] if source is not None else [])
    if len(episode_keys) != len(codes):
        raise UserError(f"the segmentation has {len(codes)} episodes but the source lists {len(episode_keys)}; "
                        "segment the demonstrations read from the source.")
    if fmt in SOURCE_FORMAT:
        from digail.data.lerobot import write_subtask_index
        from digail.data.robomimic import write_subtask_signals

        if source is None or not Path(source).exists():
            raise UserError(f"--export {fmt} copies the {fmt} source, but {source} is no longer there; put it back "
                            "and segment again.")
        try:
            if fmt == "robomimic":
                return write_subtask_signals(source, out, episode_keys, codes, names, force=force, notes=notes,
                                             reading=reading)
            return write_subtask_index(source, out, episode_keys, codes, names, force=force, reading=reading)
        except FileNotFoundError as exc:  # the source moved away while it was copied
            raise UserError(f"{exc.filename or source} disappeared while the export was written; nothing was "
                            "written, put the source back and segment again.") from None
    rows = segment_rows(episode_keys, codes, names)
    if fmt == "json":
        data = (json.dumps({"names": list(names), "reading": reading, "segments": rows}, indent=1) + "\n").encode()
    else:
        rows = [{**row, "reading": reading} for row in rows]
        buf = io.StringIO()
        writer = csv.DictWriter(buf, fieldnames=["episode", "start", "end", "code", "name", "reading"],
                                lineterminator="\n")
        writer.writeheader()
        writer.writerows(rows)
        data = buf.getvalue().encode()
    atomic_write_bytes(out, data)
    return out
