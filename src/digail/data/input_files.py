"""Input files opened safely: what the importers and `digail segment --export` read stays inside the input.

- A file is read only when it is a regular file (`regular_file`): a FIFO, a device or a socket is refused from its
  `stat`, without opening it, since opening one can block for ever (a FIFO) or never end (`/dev/zero`).
- A file a dataset's metadata names (imitation's `state.json`) or that is found below a dataset folder (LeRobot's
  Parquet files) must resolve inside that folder (`inside`): no absolute names, no `..`, no link leading out.
- JSON metadata is read with a size bound and its nesting depth caught (`read_json`).
- HDF5 files may hold only hard links with UTF-8 names (`check_h5_links`): a soft or external link, which could
  lead to another file or nowhere, is refused before anything is read, and so is a dataset whose data lives in
  another file (external or virtual storage; `h5_array`).
"""

from __future__ import annotations

import json
import os
import stat
from pathlib import Path
from typing import Any

import numpy as np

from digail.errors import UserError
from digail.fsio import file_kind as file_kind
from digail.utils import one_line

MAX_JSON_BYTES = 64 * 2**20
"""a metadata file larger than this is refused unread"""

def regular_file(path: str | os.PathLike[str], what: str = "file") -> Path:
    """`path` when it is a regular file (a link to one counts); one sentence otherwise, without opening it."""
    path = Path(path)
    try:
        mode = os.stat(path).st_mode
    except FileNotFoundError:
        gone = " (a link to nothing)" if path.is_symlink() else ""
        raise UserError(f"no {what} at {path}{gone}; check the path.") from None
    except OSError as exc:
        raise UserError(f"cannot read {path} ({one_line(exc)}); check the path and its permissions.") from None
    kind = file_kind(mode)
    if kind is not None:
        raise UserError(f"{path} is {kind}, not a regular file; digail reads only regular files, so copy the "
                        "data into one.")
    if stat.S_ISDIR(mode):
        raise UserError(f"{path} is a folder where a {what} belongs; the dataset is damaged.")
    return path


def inside(folder: str | os.PathLike[str], name: str, where: str, what: str = "file") -> Path:
    """The regular file `name` (relative, as a dataset's metadata names it, or a path found below `folder`)
    resolved inside `folder`: refused when it is absolute, climbs out with `..`, or is a link leading out."""
    folder = Path(folder)
    rel = Path(name)
    if rel.is_absolute() or ".." in rel.parts or not rel.parts:
        raise UserError(f"{where} names {what} {name!r}, which is not a file inside {folder}; digail reads only the "
                        "dataset's own files, repair the metadata.")
    path = folder / rel
    real, root = Path(os.path.realpath(path)), Path(os.path.realpath(folder))
    if real != root and root not in real.parents:
        raise UserError(f"{path} is a link to {real}, outside the dataset folder {folder}; digail reads only the "
                        "dataset's own files, copy the folder with its links resolved (`cp -rL`).")
    return regular_file(path, what)


def check_tree(folder: str | os.PathLike[str]) -> None:
    """Refuse a folder holding a FIFO, a device or a socket, or a link leading out of it or to nothing (before it is
    copied: a copy would block on a FIFO or copy what a link points to from elsewhere)."""
    folder = Path(folder)
    root = Path(os.path.realpath(folder))
    for parent, dirs, files in os.walk(folder, followlinks=False):
        for name in [*dirs, *files]:
            path = Path(parent) / name
            try:
                st = path.lstat()
                if stat.S_ISLNK(st.st_mode):
                    real = Path(os.path.realpath(path))
                    if real != root and root not in real.parents:
                        raise UserError(f"{path} is a link to {real}, outside the dataset folder {folder}; copy the "
                                        "folder with its links resolved (`cp -rL`) first.")
                    st = path.stat()
            except FileNotFoundError:
                raise UserError(f"{path} is a link to nothing; remove it or copy the dataset again.") from None
            except OSError as exc:
                raise UserError(f"cannot read {path} ({one_line(exc)}); repair the dataset folder.") from None
            kind = file_kind(st.st_mode)
            if kind is not None:
                raise UserError(f"{path} is {kind}, not a regular file; remove it from the dataset folder.")


def read_json(path: str | os.PathLike[str], what: str) -> Any:
    """The JSON value of the regular file `path`; one sentence naming `what` is damaged otherwise (unreadable, over
    `MAX_JSON_BYTES`, not JSON, nested deeper than Python's parser goes)."""
    path = regular_file(path, "metadata file")
    try:
        size = path.stat().st_size
        if size > MAX_JSON_BYTES:
            raise UserError(f"{path} holds {size // 2**20} MiB, far more than metadata does; {what} is damaged.")
        return json.loads(path.read_bytes())
    except UserError:
        raise
    except RecursionError:
        raise UserError(f"{path} nests its JSON deeper than any metadata does; {what} is damaged.") from None
    except (OSError, ValueError) as exc:  # UnicodeDecodeError is a ValueError
        raise UserError(f"cannot read {path} ({one_line(exc)}); {what} is damaged.") from None


def check_h5_links(h5: Any, where: str) -> None:
    """Refuse an HDF5 file holding a soft or external link, or a name that is not UTF-8 (one walk over its links,
    which visits each group once, so hard-link cycles end)."""
    from h5py import h5l

    found: list[tuple[bytes, int]] = []

    def visit(name: bytes, info: Any) -> None:
        if info.type != h5l.TYPE_HARD:
            found.append((name, info.type))
            return None
        try:
            name.decode("utf-8")
        except UnicodeDecodeError:
            found.append((name, -1))
        return None

    try:
        h5.id.links.visit(visit, info=True)
    except (OSError, RuntimeError, KeyError, ValueError) as exc:
        raise UserError(f"cannot read {where} as an HDF5 file ({one_line(exc)}); the file is damaged.") from None
    if not found:
        return
    name, kind = found[0]
    shown = name.decode("utf-8", "backslashreplace")
    if kind == -1:
        raise UserError(f"{where} has a group or array named '{shown}', which is not UTF-8; rename it (h5py's "
                        "`move`) before importing.")
    link = {h5l.TYPE_SOFT: "a soft link", h5l.TYPE_EXTERNAL: "an external link (to another file)"}.get(kind, "a link")
    raise UserError(f"{where} has {link} at '{shown}'; digail reads only the arrays stored in the file itself, so "
                    "copy the linked data in (h5py's `copy`) or remove the link.")


def check_declared(where: str, key: str, shape: tuple[int, ...], dtype: np.dtype[Any], stored: int | None) -> None:
    """Refuse, before reading it, an array whose header declares more bytes than the file stores for it (`stored`;
    None when compression hides it) or than this machine's memory holds."""
    from digail.utils import available_memory, human_bytes

    declared = int(np.prod(shape, dtype=object)) * int(dtype.itemsize)
    if stored is not None and declared > stored:
        raise UserError(f"{where} declares '{key}' as a {tuple(shape)} array of {human_bytes(declared)} but stores "
                        f"only {human_bytes(max(stored, 0))} of it; the file is damaged or cut short.")
    free = available_memory()
    if free is not None and declared > free:
        raise UserError(f"{where} declares '{key}' as a {tuple(shape)} array of {human_bytes(declared)}, more than "
                        f"the {human_bytes(free)} of memory available; import it on a larger machine or in parts.")


def h5_array(ds: Any, where: str, name: str) -> np.ndarray:
    """The numeric HDF5 dataset `ds` read whole, after its storage is checked: stored in this file, numeric and
    real, and every byte it declares written (a chunked dataset's chunks allocated; a contiguous one's storage)
    and within the memory available."""
    import h5py

    if not isinstance(ds, h5py.Dataset):
        raise UserError(f"{where} has '{name}' as a group where an array belongs; the file is damaged or not of "
                        "this layout.")
    try:
        if ds.is_virtual or ds.external:
            raise UserError(f"{where} stores '{name}' in another file (an external or virtual dataset); digail reads "
                            "only the arrays stored in the file itself.")
        if ds.dtype.kind == "c":  # a cast to float would drop the imaginary part without a word
            raise UserError(f"{where} has complex values in '{name}'; digail reads real numbers only, so save the "
                            "real and imaginary parts as separate columns.")
        if ds.dtype.kind not in "biuf":  # strings, structured records, references, opaque bytes
            raise UserError(f"{where} has '{name}' of dtype {ds.dtype}; it must be a numeric array.")
        contiguous = ds.chunks is None and ds.compression is None
        # a contiguous uncompressed dataset stores every byte it declares, inside the file; compressed chunks may
        # hold more than their bytes, so only the memory bounds them
        stored = min(int(ds.id.get_storage_size()), Path(ds.file.filename).stat().st_size) if contiguous else None
        check_declared(where, name, ds.shape, ds.dtype, stored)
        if ds.chunks is not None and ds.size:
            need = int(np.prod([-(-s // c) for s, c in zip(ds.shape, ds.chunks, strict=True)], dtype=object))
            if ds.id.get_num_chunks() < need:  # chunks never written read as the fill value
                raise UserError(f"{where} declares '{name}' as a {ds.shape} array but writes only part of it; the "
                                "file is damaged or cut short.")
        return np.asarray(ds[()])
    except UserError:
        raise
    except (OSError, RuntimeError, KeyError, ValueError, TypeError) as exc:
        raise UserError(f"cannot read '{name}' from {where} ({one_line(exc)}); the file is damaged.") from None


def as_float32(arr: np.ndarray, where: str, key: str) -> np.ndarray:
    """An array as float32, digail's type for observations: finite values beyond its range are refused as what
    they are (stored as float32 they would become inf and be reported as "NaN or inf")."""
    if (np.issubdtype(arr.dtype, np.floating) and arr.dtype.itemsize > 4 and arr.size
            and np.abs(np.where(np.isfinite(arr), arr, 0)).max() > np.finfo(np.float32).max):
        raise UserError(f"{where} has values in {key!r} beyond float32's range (about 3.4e38 in size), which is how "
                        "digail stores demonstrations; rescale them before importing.")
    return arr.astype(np.float32)
