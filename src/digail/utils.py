"""Small shared helpers: seeding, run folders, atomic writes, torch threads."""

from __future__ import annotations

import contextlib
import json
import os
import random
import shutil
import tempfile
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np
import torch

from digail.errors import UserError


def seed_everything(seed: int) -> np.random.Generator:
    """Seed Python, NumPy and torch; return a fresh NumPy generator for the caller's own draws."""
    random.seed(seed)
    np.random.seed(seed % 2**32)
    torch.manual_seed(seed)
    return np.random.default_rng(seed)


def set_torch_threads(n: int = 1) -> None:
    """2x64 nets gain nothing from a second thread and get much noisier under load; default to one."""
    torch.set_num_threads(n)


def resolve_device(device: str) -> torch.device:
    """`auto` picks CUDA when present, else CPU; an unavailable explicit device is a user error."""
    if device == "auto":
        return torch.device("cuda" if torch.cuda.is_available() else "cpu")
    if device.startswith("cuda") and not torch.cuda.is_available():
        raise UserError(f"--device {device} was asked for but CUDA is not available; use --device cpu.")
    try:
        return torch.device(device)
    except RuntimeError as exc:
        raise UserError(f"unknown device {device!r}; use cpu, cuda or auto.") from exc


def default_run_dir(env_id: str, method: str, seed: int, root: str | Path = "runs") -> Path:
    """`runs/<env>__<method>__s<seed>__<time>` with the env id made filesystem-safe."""
    safe_env = env_id.replace("/", "-")
    stamp = time.strftime("%Y%m%d-%H%M%S")
    return Path(root) / f"{safe_env}__{method}__s{seed}__{stamp}"


def check_new_dir(path: Path, force: bool) -> None:
    """Refuse to overwrite an existing output folder unless `force`."""
    if path.exists() and not force:
        raise UserError(f"output folder {path} already exists; choose another --out or pass --force.")


@contextlib.contextmanager
def atomic_dir(final: Path, force: bool = False) -> Iterator[Path]:
    """Yield a temporary sibling folder; rename it to `final` only if the block succeeds.

    Nothing half-written is left behind on error: the temporary folder is removed.
    """
    final = Path(final)
    check_new_dir(final, force)
    final.parent.mkdir(parents=True, exist_ok=True)
    tmp = Path(tempfile.mkdtemp(prefix=f".{final.name}.tmp-", dir=final.parent))
    try:
        yield tmp
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        raise
    if final.exists():
        shutil.rmtree(final)
    os.replace(tmp, final)


def atomic_write_bytes(path: Path, data: bytes) -> None:
    """Write to a temporary file in the same folder, then rename over `path`."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", dir=path.parent)
    try:
        with os.fdopen(fd, "wb") as f:
            f.write(data)
        os.replace(tmp, path)
    except BaseException:
        with contextlib.suppress(FileNotFoundError):
            os.unlink(tmp)
        raise


def write_json(path: Path, obj: Any) -> None:
    """Atomically write `obj` as indented JSON (NumPy scalars and arrays converted)."""

    atomic_write_bytes(Path(path), (json.dumps(obj, indent=2, default=json_default) + "\n").encode())


def json_default(o: Any) -> Any:
    """`json.dumps(default=...)` for NumPy scalars and arrays and paths."""
    if isinstance(o, np.generic):
        return o.item()
    if isinstance(o, np.ndarray):
        return o.tolist()
    if isinstance(o, Path):
        return str(o)
    raise TypeError(f"not JSON serialisable: {type(o).__name__}")


def one_line(exc: BaseException) -> str:
    """An exception's message as one line without a final full stop (for `UserError` sentences)."""
    text = " ".join(str(exc).split())
    return text.rstrip(".") if text else type(exc).__name__


def progress_bar(total: int, enabled: bool, desc: str = "VAE", unit: str = "epoch") -> Any:
    """A tqdm bar for a long loop (None when `enabled` is False)."""
    if not enabled:
        return None
    from tqdm.auto import tqdm

    return tqdm(total=total, desc=desc, unit=unit, mininterval=0.5, dynamic_ncols=True)
