"""A segmentation written back where other tools look for sub-task annotations.

Four targets (`EXPORTS`):

- `robomimic`: a copy of the robomimic file the demonstrations came from, with MimicGen's
  `datagen_info/subtask_term_signals/<name>` per demonstration (`digail.data.robomimic.write_subtask_signals`).
- `lerobot`: a copy of the LeRobot dataset with a per-frame `subtask_index` column and `meta/subtasks.parquet`
  (`digail.data.lerobot.write_subtask_index`).
- `csv`, `json`: a plain table of segments, one row per segment: `episode` (the episode's name in its source),
  `start`, `end` (the segment covers steps start .. end - 1), `code`, `name`.

Steps are the demonstration's action steps as digail read them; the input is never written.
"""

from __future__ import annotations

import csv
import io
import json
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from digail.errors import UserError
from digail.fsio import atomic_write_bytes, check_writable

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
    if len(set(names)) != len(names) or any(not n or "/" in n for n in names):
        raise UserError("--names must be distinct, non-empty and without '/'; they name HDF5 datasets and table "
                        "rows.")
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


def check_export(fmt: str, out: Path | None, source: str | None, source_format: str | None, force: bool) -> None:
    """Refuse, before any work, an export that cannot be written: no `--out`, an existing one without `force`, an
    annotated copy of a source that is not of its layout or no longer there."""
    if fmt not in EXPORTS:
        raise UserError(f"unknown export {fmt!r}; choose one of {', '.join(EXPORTS)}.")
    if out is None:
        raise UserError(f"--export {fmt} needs --out: the file or folder to write.")
    if out.exists() and not force:
        raise UserError(f"output {out} already exists; choose another --out or pass --force.")
    check_writable(out)
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
    if Path(out).resolve() == Path(source).resolve():
        raise UserError(f"--out {out} is the input; digail never modifies its input, choose another --out.")


def export_segmentation(fmt: str, out: Path, episode_keys: Sequence[str], codes: Sequence[np.ndarray],
                        names: Sequence[str], *, source: str | None = None, force: bool = False) -> Path:
    """Write the codes of each episode to `out` in `fmt` (see the module docstring); returns `out`.

    Args:
        fmt: one of `EXPORTS`.
        out: the file (robomimic, csv, json) or folder (lerobot) to write; never the source.
        episode_keys: each episode's name in its source (`Imported.episode_keys`).
        codes: one (T,) array of codes per episode, in the order of `episode_keys`.
        names: one name per code (`code_names`).
        source: the robomimic file or LeRobot folder to copy (for those two exports).
        force: replace an existing `out`.
    """
    out = Path(out)
    if len(episode_keys) != len(codes):
        raise UserError(f"the segmentation has {len(codes)} episodes but the source lists {len(episode_keys)}; "
                        "segment the demonstrations read from the source.")
    if fmt == "robomimic":
        from digail.data.robomimic import write_subtask_signals

        assert source is not None
        return write_subtask_signals(source, out, episode_keys, codes, names, force=force)
    if fmt == "lerobot":
        from digail.data.lerobot import write_subtask_index

        assert source is not None
        return write_subtask_index(source, out, episode_keys, codes, names, force=force)
    rows = segment_rows(episode_keys, codes, names)
    if fmt == "json":
        data = (json.dumps({"names": list(names), "segments": rows}, indent=1) + "\n").encode()
    else:
        buf = io.StringIO()
        writer = csv.DictWriter(buf, fieldnames=["episode", "start", "end", "code", "name"], lineterminator="\n")
        writer.writeheader()
        writer.writerows(rows)
        data = buf.getvalue().encode()
    atomic_write_bytes(out, data)
    return out
