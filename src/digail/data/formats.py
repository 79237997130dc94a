"""The structured layouts `digail.data.importers.read_demonstrations` reads besides named arrays: which one a
file or folder is (detection), and the reader of each.

| layout | what is detected | reader |
| --- | --- | --- |
| `imitation-dataset` | a folder with `state.json` and `dataset_info.json` | `digail.data.imitation_hf` |
| `lerobot` | a folder with `meta/info.json` | `digail.data.lerobot` |
| `robomimic` | an HDF5 file with `data/demo_<n>` groups | `digail.data.robomimic` |

Anything else goes on to the named-array layouts (`.npz` and flat HDF5 files).
"""

from __future__ import annotations

import os
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from digail.errors import UserError

STRUCTURED = ("imitation-dataset", "lerobot", "robomimic")
"""the layouts read here"""

FOLDER_LAYOUTS = ("an imitation trajectories folder (state.json, dataset_info.json and .arrow files, as "
                  "imitation.data.serialize.save writes), a LeRobot dataset (meta/info.json and Parquet files below "
                  "data/)")


def detect(path: Path) -> str | None:
    """The structured layout at `path`, or None (not a folder of one, nor a robomimic file)."""
    from digail.data.imitation_hf import is_imitation_folder
    from digail.data.lerobot import is_lerobot
    from digail.data.robomimic import is_robomimic

    if path.is_dir():
        if is_imitation_folder(path):
            return "imitation-dataset"
        if is_lerobot(path):
            return "lerobot"
        return None
    if path.suffix.lower() in (".hdf5", ".h5") and is_robomimic(path):
        return "robomimic"
    return None


def read_structured(source: str | os.PathLike[str], fmt: str,
                    obs_keys: Sequence[str] | None) -> dict[str, Any] | None:
    """`source` read as a structured layout (`fmt`, or the detected one under "auto"), or None when it is none
    of them and should be read as named arrays.

    Returns:
        The reader's dict (`episodes`, `notes`, `found`, `episode_keys`, `metadata`) with `fmt` and `source`
        added, which `digail.data.importers.read_demonstrations` checks and turns into an `Imported`.

    Raises:
        UserError: a folder of no layout digail reads (naming those it tried), a file that is not the layout
            `fmt` names, or what the layout's reader refuses.
    """
    path = Path(source)
    if fmt == "imitation" and path.is_dir():
        fmt = "imitation-dataset"
    kind = detect(path) if fmt == "auto" else fmt
    if kind is None and path.is_dir():
        if (path / "data" / "metadata.json").is_file() or (path / "metadata.json").is_file():
            raise UserError(f"{path} is a Minari dataset folder, which needs no import; pass it to --demos as it "
                            "is.")
        raise UserError(f"{path} is a folder but none of the layouts digail imports: tried {FOLDER_LAYOUTS}; for "
                        "arrays, pass the .npz or HDF5 file itself.")
    if kind not in STRUCTURED:
        return None
    if not path.exists():
        raise UserError(f"no {'folder' if kind != 'robomimic' else 'file'} at {path}; pass the path of the "
                        f"{kind} demonstrations.")
    if kind == "robomimic":
        from digail.data.robomimic import is_robomimic, read_robomimic

        if not is_robomimic(path):
            raise UserError(f"{path} is not a robomimic file: it has no data/demo_<n> groups; check the path, or "
                            "drop --format to detect the layout.")
        read = read_robomimic(path, obs_keys)
    elif kind == "lerobot":
        from digail.data.lerobot import is_lerobot, read_lerobot

        if not is_lerobot(path):
            raise UserError(f"{path} is not a LeRobot dataset: it has no meta/info.json; pass the dataset's root "
                            "folder, or drop --format to detect the layout.")
        read = read_lerobot(path, obs_keys)
    else:
        from digail.data.imitation_hf import is_imitation_folder, read_imitation_folder

        if not is_imitation_folder(path):
            raise UserError(f"{path} is not an imitation trajectories folder: it lacks state.json or "
                            "dataset_info.json; pass the folder imitation.data.serialize.save wrote.")
        if obs_keys:
            raise UserError("--obs-keys applies to robomimic files and LeRobot datasets; drop it for imitation's "
                            "trajectories.")
        read = read_imitation_folder(path)
    return {**read, "fmt": kind, "source": os.fspath(path)}
