"""Publishing a sweep's table: the median seed's run folder copied beside the table, and the table's Markdown put
between a page's two markers (what the generators of the published tables in `benchmarks/` share)."""

from __future__ import annotations

import io
import os
import shutil
from collections.abc import Sequence
from pathlib import Path
from typing import Any

PUBLISH_FILES = ("model.pt", "config.json", "eval.json", "metrics.csv", "segmentation.json")
"""a run folder's small files (no checkpoint, no TensorBoard): enough for `digail evaluate` to re-check a cell"""


def median_seed(seeds: Sequence[dict[str, Any]], key: str = "mean_return") -> dict[str, Any]:
    """The record of the median seed by `key` (the lower middle of an even count)."""
    ordered = sorted(seeds, key=lambda r: r[key])
    return ordered[(len(ordered) - 1) // 2]


def publish_run(src: Path, dest: Path) -> None:
    """Copy a run folder's small files (and figures) to `dest`, replacing the folder of another seed of the same
    cell (`<cell>_s<seed>` beside it)."""
    prefix = dest.name.rsplit("_s", 1)[0]
    for old in dest.parent.glob(f"{prefix}_s*"):
        if old != dest:
            shutil.rmtree(old)
    dest.mkdir(parents=True, exist_ok=True)
    for name in PUBLISH_FILES:
        if (src / name).exists():
            shutil.copy2(src / name, dest / name)
    if (src / "figures").is_dir():
        shutil.copytree(src / "figures", dest / "figures", dirs_exist_ok=True)
    make_portable(dest)


def portable_text(text: str, root: str | os.PathLike[str] | None = None) -> str:
    """`text` with every absolute path below `root` (default: the working directory, the repository's root for the
    publishing scripts) written relative to it: a published command or run folder then reads the same on any
    checkout. Only the published copy is rewritten: the run's own `config.json` keeps its absolute paths, which a
    later command on the machine that ran it needs from any directory."""
    prefix = os.path.join(os.path.realpath(root if root is not None else os.getcwd()), "")
    return text.replace(prefix, "")


def make_portable(folder: Path, root: str | os.PathLike[str] | None = None) -> None:
    """Rewrite a published run folder's `config.json` and the config stored in its `model.pt` with
    `portable_text`; the checkpoint's tensors are saved again untouched."""
    import torch

    from digail.fsio import atomic_write_bytes

    config = folder / "config.json"
    if config.is_file():
        config.write_text(portable_text(config.read_text(), root))
    model = folder / "model.pt"
    if model.is_file():
        payload = torch.load(model, map_location="cpu", weights_only=True)
        text = payload.get("config_json") if isinstance(payload, dict) else None
        if isinstance(text, str) and portable_text(text, root) != text:
            payload["config_json"] = portable_text(text, root)
            buf = io.BytesIO()
            torch.save(payload, buf)
            atomic_write_bytes(model, buf.getvalue())


def replace_between_markers(page: Path, markers: tuple[str, str], text: str) -> None:
    """Put `text` between the two `markers` of the Markdown file `page` (each on a line of its own)."""
    content = page.read_text()
    start, end = content.index(markers[0]) + len(markers[0]), content.index(markers[1])
    page.write_text(content[:start] + "\n" + text + "\n" + content[end:])
