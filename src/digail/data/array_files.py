"""Array files opened for the importers (`digail.data.importers`): `.npz` and HDF5 files, and dicts of arrays,
behind one checked view.

Each array is checked as it is taken (numeric, finite, within float32's range, no pickled objects), and a size a
file's header declares is checked against the bytes it stores and the free memory before anything is read, so a
damaged or hostile file gets one sentence instead of a traceback or an allocation of terabytes.
"""

from __future__ import annotations

import os
import zipfile
import zlib
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import numpy as np

from digail.data.input_files import check_declared, check_h5_links, regular_file
from digail.errors import UserError
from digail.utils import one_line

FILE_SUFFIXES = (".npz", ".hdf5", ".h5")
"""files `read_demonstrations` opens (anything else is taken for a Minari dataset by the commands)"""

LAYOUTS = ("SB3 rollouts (obs, actions, episode_starts), imitation trajectories (obs, acts, indices, terminal), "
            "imitation transitions (obs, acts, next_obs, dones), D4RL arrays (observations, actions, terminals, "
            "timeouts), plain arrays (observations, actions, episode_ends) or a robomimic file (data/demo_<n> "
            "groups)")

REQUIRED = {
    "imitation-transitions": ("obs", "acts", "next_obs", "dones"),
    "sb3": ("obs", "actions", "episode_starts"),
    "imitation": ("obs", "acts", "indices", "terminal"),
    "d4rl": ("observations", "actions"),
    "arrays": ("actions|acts", "observations|obs", "episode_ends"),
}


class Arrays:
    """Named arrays of one source, checked as they are taken: numeric, finite, no pickled objects."""

    def __init__(self, where: str, data: Mapping[str, Any]) -> None:
        self.where, self.data = where, data

    def __contains__(self, key: str) -> bool:
        return key in self.data

    def keys(self) -> list[str]:
        return sorted(self.data)

    def get(self, key: str, *, kind: str = "number") -> np.ndarray:
        """Array `key`; `kind` "number" (finite numbers), "flag" (bools or 0/1) or "index" (integers)."""
        try:
            arr = np.asarray(self.data[key])
        except KeyError:
            raise UserError(f"{self.where} has no '{key}' array; {self._hint()}.") from None
        except UserError:
            raise
        except ValueError as exc:  # NpzFile refuses object arrays without pickle
            raise UserError(f"{self.where} stores '{key}' as pickled Python objects ({one_line(exc)}), which digail "
                            "never loads; save it as a numeric array.") from None
        if arr.dtype == object or not (np.issubdtype(arr.dtype, np.number) or arr.dtype == np.bool_):
            raise UserError(f"{self.where} has '{key}' of dtype {arr.dtype}; it must be a numeric array.")
        if arr.ndim == 0:
            raise UserError(f"{self.where} has '{key}' as a single number; it must be an array with a row per step "
                            "(or per episode).")
        if np.iscomplexobj(arr):  # a cast to float would drop the imaginary part without a word
            raise UserError(f"{self.where} has complex values in '{key}'; digail reads real numbers only, so save "
                            "the real and imaginary parts as separate columns.")
        if kind == "number" and np.issubdtype(arr.dtype, np.floating) and not np.all(np.isfinite(arr)):
            raise UserError(f"{self.where} has NaN or inf values in '{key}'; drop or repair those steps before "
                            "importing.")
        if (kind == "number" and np.issubdtype(arr.dtype, np.floating) and arr.dtype.itemsize > 4 and arr.size
                and np.abs(arr).max() > np.finfo(np.float32).max):  # finite here, inf once stored as float32
            raise UserError(f"{self.where} has values in '{key}' beyond float32's range (about 3.4e38 in size), "
                            "which is how digail stores demonstrations; rescale them before importing.")
        if kind == "flag":
            if arr.dtype != np.bool_ and not np.isin(arr, (0, 1)).all():
                raise UserError(f"{self.where} has '{key}' values other than True/False (or 0/1); it must hold "
                                "one flag per row.")
            arr = arr.astype(bool)
        if kind == "index" and not np.issubdtype(arr.dtype, np.integer):
            raise UserError(f"{self.where} has '{key}' of dtype {arr.dtype}; it must hold integer indices.")
        return arr

    def optional(self, key: str, kind: str = "number") -> np.ndarray | None:
        return self.get(key, kind=kind) if key in self.data else None

    def first(self, *keys: str) -> np.ndarray:
        for key in keys:
            if key in self.data:
                return self.get(key)
        raise UserError(f"{self.where} has no '{keys[0]}' array; {self._hint()}.")

    def _hint(self) -> str:
        return f"it holds {', '.join(self.keys()) or 'no arrays'}, expected {LAYOUTS}"


def open_arrays(source: str | os.PathLike[str] | Mapping[str, Any]) -> tuple[Arrays, Any]:
    """The arrays of a file or dict, and the open file to close (or None)."""
    if isinstance(source, Mapping):
        return Arrays("the given arrays", source), None
    path = Path(source)
    where = str(path)
    if path.is_dir():
        raise UserError(f"{where} is a folder; pass an .npz or HDF5 file (a Minari dataset folder needs no "
                        "import).")
    if not path.exists():
        raise UserError(f"no file at {where}; pass the path of an .npz or HDF5 file of demonstrations.")
    regular_file(path, "demonstrations file")  # a FIFO or a device is refused before it is opened
    suffix = path.suffix.lower()
    if suffix == ".npz":
        try:
            npz = np.load(path, allow_pickle=False)
        except ValueError as exc:
            if "pickle" not in str(exc):
                raise UserError(f"cannot read {where} as an .npz file ({one_line(exc)}); the file is damaged or not "
                                "written by numpy.savez.") from exc
            # numpy takes anything that is neither a zip nor an .npy for a pickle, and its text would suggest
            # loading it unsafely
            with open(path, "rb") as f:
                pickled = f.read(1) == b"\x80"  # the opcode every pickle since protocol 2 starts with
            if pickled:
                raise UserError(f"{where} is a Python pickle, not an .npz file, and digail never loads pickles; save "
                                "the arrays with numpy.savez.") from None
            raise UserError(f"cannot read {where} as an .npz file (it is neither a zip archive nor an .npy array); "
                            "the file is damaged or not written by numpy.savez.") from None
        except (OSError, EOFError, zipfile.BadZipFile, NotImplementedError, RuntimeError) as exc:
            raise UserError(f"cannot read {where} as an .npz file ({one_line(exc)}); the file is damaged or not "
                            "written by numpy.savez.") from exc
        if not hasattr(npz, "files"):
            raise UserError(f"{where} holds a single array, not named arrays; save them with numpy.savez(path, "
                            "obs=..., actions=..., ...).")
        return Arrays(where, {k: _LazyNpz(npz, k, where) for k in npz.files}), npz
    if suffix in (".hdf5", ".h5"):
        import h5py

        try:
            h5 = h5py.File(path, "r")
        except OSError as exc:
            raise UserError(f"cannot read {where} as an HDF5 file ({one_line(exc)}); the file is damaged or not "
                            "HDF5.") from exc
        try:
            check_h5_links(h5, where)
            arrays = {k: _LazyH5(h5, k, where) for k, v in h5.items() if isinstance(v, h5py.Dataset)}
        except BaseException:
            h5.close()
            raise
        return Arrays(where, arrays), h5
    raise UserError(f"{where} is neither an .npz nor an HDF5 file; save the demonstrations with numpy.savez or "
                    "h5py.")


class _LazyNpz:
    """An npz member read only when used (so that an unused pickled `infos` costs nothing and loads nothing); its
    header's declared size is checked against the member and the memory before it is read."""

    def __init__(self, npz: Any, key: str, where: str) -> None:
        self.npz, self.key, self.where = npz, key, where

    def __array__(self, dtype: Any = None, copy: Any = None) -> np.ndarray:
        damaged = f"cannot read '{self.key}' from {self.where}"
        try:
            name = self.key if self.key in self.npz.zip.namelist() else f"{self.key}.npy"
            info = self.npz.zip.getinfo(name)
            with self.npz.zip.open(info) as f:
                version = np.lib.format.read_magic(f)
                reader = {(1, 0): np.lib.format.read_array_header_1_0,
                          (2, 0): np.lib.format.read_array_header_2_0}.get(version)
                header = None if reader is None else reader(f)
                if header is not None and not header[2].hasobject:
                    check_declared(self.where, self.key, header[0], header[2], info.file_size - f.tell())
            arr = self.npz[self.key]
        except UserError:
            raise
        except ValueError as exc:
            if "allow_pickle" in str(exc):
                raise  # pickled objects: named as such by `Arrays.get`
            raise UserError(f"{damaged} ({one_line(exc)}); the file is damaged.") from None
        except (OSError, EOFError, KeyError, zipfile.BadZipFile, zlib.error, NotImplementedError, RuntimeError) as exc:
            # NotImplementedError: an unknown compression method; RuntimeError: an encrypted member
            raise UserError(f"{damaged} ({one_line(exc)}); the file is damaged or cut short.") from None
        return arr if dtype is None else arr.astype(dtype)


class _LazyH5:
    def __init__(self, h5: Any, key: str, where: str) -> None:
        self.h5, self.key, self.where = h5, key, where

    def __array__(self, dtype: Any = None, copy: Any = None) -> np.ndarray:
        from digail.data.input_files import h5_array

        try:
            ds = self.h5[self.key]
        except (OSError, KeyError) as exc:
            raise UserError(f"cannot read '{self.key}' from {self.where} ({one_line(exc)}); the file is damaged.") \
                from exc
        arr = h5_array(ds, self.where, self.key)
        return arr if dtype is None else arr.astype(dtype)


def class_of(arrays: Arrays) -> str:
    if "indices" in arrays and "acts" in arrays:
        return "imitation"
    if all(k in arrays for k in REQUIRED["imitation-transitions"]):
        return "imitation-transitions"
    if "episode_starts" in arrays:
        return "sb3"
    if "episode_ends" in arrays:
        return "arrays"
    if "terminals" in arrays or "timeouts" in arrays:
        return "d4rl"
    raise UserError(f"{arrays.where} holds {', '.join(arrays.keys()) or 'no arrays'}, which is none of the layouts "
                    f"digail reads: {LAYOUTS}.")
