"""Moving run folders between the driver's sweep folder and the nodes that run its trials, through Ray.

No filesystem shared by the nodes is needed: a trial that runs on another node than the driver gets the folders it
reads (its VAE, its own run folder with any checkpoint, its state and log) packed into the task's arguments, works
in a scratch folder of its own node, and sends its folders back - while it trains, each time its checkpoint changes
(to a small mailbox actor the driver empties), and when it ends (in the task's result). The driver unpacks them into
`--out`, so a retry on a third node starts from the last checkpoint that reached the driver.

A pack is a gzipped tar of paths relative to the sweep folder; unpacking replaces each path as a whole, so a run
folder that a retry rewrote from scratch leaves no file of the earlier attempt behind.
"""

from __future__ import annotations

import contextlib
import io
import json
import os
import shutil
import tarfile
import tempfile
from pathlib import Path, PurePosixPath
from typing import Any

from digail.errors import UserError

MANIFEST = ".digail-pack.json"
"""the member of a pack that lists the paths it carries (a path absent from the sweep folder is listed as gone)"""


def _safe(rel: str) -> str:
    """`rel` if it names a path inside the sweep folder (relative, no '..'), else a ValueError."""
    parts = PurePosixPath(rel).parts
    if not parts or PurePosixPath(rel).is_absolute() or ".." in parts:
        raise ValueError(f"pack path {rel!r} leaves the sweep folder")
    return str(PurePosixPath(*parts))


def pack(root: Path | str, paths: list[str]) -> bytes:
    """The files and folders `paths` (relative to `root`) as one gzipped tar; missing paths are recorded as such."""
    root = Path(root)
    buf = io.BytesIO()
    present = []
    with tarfile.open(fileobj=buf, mode="w:gz", compresslevel=1) as tar:
        for rel in dict.fromkeys(_safe(p) for p in paths):
            if (root / rel).exists():
                tar.add(root / rel, arcname=rel)
                present.append(rel)
        manifest = json.dumps({"paths": present}).encode()
        info = tarfile.TarInfo(MANIFEST)
        info.size = len(manifest)
        tar.addfile(info, io.BytesIO(manifest))
    return buf.getvalue()


def unpack(data: bytes, root: Path | str) -> list[str]:
    """Put a pack's paths into `root`, each replacing what was there; returns them."""
    root = Path(root)
    root.mkdir(parents=True, exist_ok=True)
    stage = Path(tempfile.mkdtemp(prefix=".incoming-", dir=root))
    try:
        with tarfile.open(fileobj=io.BytesIO(data), mode="r:gz") as tar:
            tar.extractall(stage, filter="data")  # refuses absolute paths, '..' and links leaving the folder
        paths = [_safe(p) for p in json.loads((stage / MANIFEST).read_text())["paths"]]
        for rel in paths:
            dest = root / rel
            dest.parent.mkdir(parents=True, exist_ok=True)
            if dest.is_dir() and not dest.is_symlink():
                old = dest.with_name(f".{dest.name}.old-{os.getpid()}")
                os.replace(dest, old)
                os.replace(stage / rel, dest)
                shutil.rmtree(old, ignore_errors=True)
            else:
                os.replace(stage / rel, dest)
        return paths
    finally:
        shutil.rmtree(stage, ignore_errors=True)


class Mailbox:
    """A Ray actor on the driver's node holding the newest pack each running trial sent (one per job id)."""

    def __init__(self) -> None:
        self.packs: dict[str, bytes] = {}

    def put(self, job_id: str, data: bytes) -> None:
        self.packs[job_id] = data

    def take(self) -> dict[str, bytes]:
        packs, self.packs = self.packs, {}
        return packs


def mailbox_actor(driver_node: str | None) -> Any:
    """Start the mailbox on the driver's node (on the head node when the driver is a Ray Client)."""
    import ray
    from ray.util.scheduling_strategies import NodeAffinitySchedulingStrategy

    cls = ray.remote(num_cpus=0, max_restarts=0)(Mailbox)
    if driver_node is not None:
        return cls.options(scheduling_strategy=NodeAffinitySchedulingStrategy(driver_node, soft=False)).remote()
    return cls.options(resources={"node:__internal_head__": 0.001}).remote()


def check_pack_size(data: bytes, what: str, limit: int = 2 * 1024**3) -> bytes:
    """`data` unless it is too large to travel through Ray's object store."""
    if len(data) > limit:
        raise UserError(f"{what} packs to {len(data) / 1024**3:.1f} GiB, too much to send through Ray; put the "
                        "sweep folder on a filesystem every node sees and pass --shared-fs.")
    return data


def scratch_dir() -> Path:
    """A fresh working folder on this node for one trial attempt."""
    return Path(tempfile.mkdtemp(prefix="digail-trial-"))


def remove(path: Path) -> None:
    """Remove a scratch folder (quietly: it is only a copy)."""
    with contextlib.suppress(OSError):
        shutil.rmtree(path)
