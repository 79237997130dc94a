"""Publishing a sweep's table: the median seed's run folder copied beside the table, and the table's Markdown put
between a page's two markers (what the generators of the published tables in `benchmarks/` share)."""

from __future__ import annotations

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


def replace_between_markers(page: Path, markers: tuple[str, str], text: str) -> None:
    """Put `text` between the two `markers` of the Markdown file `page` (each on a line of its own)."""
    content = page.read_text()
    start, end = content.index(markers[0]) + len(markers[0]), content.index(markers[1])
    page.write_text(content[:start] + "\n" + text + "\n" + content[end:])
