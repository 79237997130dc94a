"""imitation (>= 1.0) demonstrations as that library saves them, read with pyarrow and numpy alone.

Two layouts:

- `imitation-dataset`: the folder `imitation.data.serialize.save(path, trajectories)` writes, a HuggingFace
  `datasets` folder (`dataset_info.json`, `state.json`, `data-*.arrow`) with one row per trajectory: `obs`
  (T + 1 observations), `acts` (T), `infos` (T JSON strings), `terminal`, and `rews` (T) for trajectories with
  rewards. The Arrow files are read directly; neither `datasets` nor imitation is needed.
- `imitation-transitions`: `imitation.data.rollout.flatten_trajectories` saved with `numpy.savez`: `obs`, `acts`,
  `next_obs`, `dones` (one row per transition; `dones` is True only on the last transition of a trajectory that
  terminated). A trajectory also ends where `next_obs` is not the next row's `obs` (the end of a trajectory cut by
  a time limit, which `dones` does not mark).

imitation sets `terminal` on every trajectory a vectorised env ended, time limits included, and records the time
limit in the last step's info as `TimeLimit.truncated` (Stable-Baselines3's wrapper). Where the infos say so, the
trajectory is kept as truncated, not terminated.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import numpy as np

from digail.data.input_files import inside, read_json
from digail.errors import UserError
from digail.utils import one_line

TIME_LIMIT_KEY = "TimeLimit.truncated"
"""the info key Stable-Baselines3's vectorised envs set on an episode cut by a time limit"""


def is_imitation_folder(path: str | Path) -> bool:
    """Whether `path` is a HuggingFace `datasets` folder (what imitation's `serialize.save` writes)."""
    path = Path(path)
    return path.is_dir() and (path / "state.json").is_file() and (path / "dataset_info.json").is_file()


def _arrow_files(path: Path) -> list[Path]:
    """The folder's Arrow files in the order `state.json` lists them (sorted names when it lists none)."""
    state = read_json(path / "state.json", "the datasets folder")
    try:
        names = [entry["filename"] for entry in state.get("_data_files", [])]
        if not all(isinstance(n, str) for n in names):
            raise TypeError("a file name that is not text")
    except (KeyError, TypeError, AttributeError) as exc:
        raise UserError(f"cannot read {path / 'state.json'} ({one_line(exc)}); the datasets folder is damaged, "
                        "save it again with imitation.data.serialize.save.") from exc
    if not names:
        names = sorted(f.name for f in path.glob("*.arrow"))
    if not names:
        raise UserError(f"{path} is a datasets folder without its data (no .arrow file); copy the whole folder "
                        "imitation.data.serialize.save wrote.")
    where = str(path / "state.json")
    for name in names:  # the names come from state.json: never ../x or /etc/passwd, checked before any is opened
        if not (path / name).exists() and not Path(name).is_absolute() and ".." not in Path(name).parts:
            raise UserError(f"{path} is a datasets folder without its data ({name}); copy the whole folder "
                            "imitation.data.serialize.save wrote.")
    return [inside(path, name, where, "data file") for name in names]


def _read_table(files: list[Path]) -> Any:
    import pyarrow as pa

    tables = []
    for file in files:
        try:
            with pa.memory_map(str(file)) as source:
                try:  # `datasets` writes the Arrow streaming format; the file format is accepted as well
                    tables.append(pa.ipc.open_stream(source).read_all())
                except pa.ArrowInvalid:
                    source.seek(0)
                    tables.append(pa.ipc.open_file(source).read_all())
        except (OSError, pa.ArrowInvalid) as exc:
            raise UserError(f"cannot read {file} as an Arrow file ({one_line(exc)}); the file is damaged.") from exc
    return pa.concat_tables(tables) if len(tables) > 1 else tables[0]


def _cell(column: Any, i: int, where: str, name: str) -> np.ndarray:
    """Row `i` of a (nested) list column as an array (its values checked later as the importers check arrays)."""
    value = column[i].as_py()
    try:
        return np.asarray(value)
    except ValueError:  # rows of different lengths inside one trajectory
        raise UserError(f"{where}, trajectory {i} has '{name}' rows of different lengths; every step needs the "
                        "same size.") from None


def read_imitation_folder(path: str | Path) -> dict[str, Any]:
    """Trajectories from an imitation datasets folder; see the module docstring.

    Returns:
        A dict with `episodes` (per trajectory its arrays, as `digail.data.importers.trajectories_from_episodes`
        takes them), `notes`, `found`, `episode_keys` (the row numbers) and `metadata`, which
        `digail.data.importers.read_demonstrations` checks and turns into an `Imported`.

    Raises:
        UserError: a missing column, an unreadable file, trajectories whose arrays do not fit together.
    """
    path = Path(path)
    table = _read_table(_arrow_files(path))
    where = str(path)
    columns = set(table.column_names)
    missing = [c for c in ("obs", "acts", "terminal") if c not in columns]
    if missing:
        raise UserError(f"{where} is a datasets folder with columns {', '.join(sorted(columns))}, not imitation's "
                        f"trajectories: it lacks {', '.join(missing)} (imitation writes obs, acts, infos, terminal "
                        "and rews).")
    obs_col, acts_col, term_col = (table.column(c).combine_chunks() for c in ("obs", "acts", "terminal"))
    rews_col = table.column("rews").combine_chunks() if "rews" in columns else None
    infos_col = table.column("infos").combine_chunks() if "infos" in columns else None
    eps, kept_truncated = [], 0
    for i in range(table.num_rows):
        terminal = bool(term_col[i].as_py())
        if terminal and infos_col is not None and _time_limited(infos_col[i].as_py()):
            terminal, kept_truncated = False, kept_truncated + 1
        eps.append({"where": f"{where}, trajectory {i}", "obs": _cell(obs_col, i, where, "obs"),
                    "acts": _cell(acts_col, i, where, "acts"),
                    "rews": None if rews_col is None else _cell(rews_col, i, where, "rews"), "terminated": terminal})
    if not eps:
        raise UserError(f"{where} holds no trajectories; save at least one.")
    notes = []
    if kept_truncated:
        notes.append(f"{kept_truncated} of {len(eps)} trajectories flagged terminal end with '{TIME_LIMIT_KEY}' "
                     "in their last info and were kept as truncated (a time limit, not a terminal state)")
    fields = [c for c in ("obs", "acts", "infos", "terminal", "rews") if c in columns]
    found = (f"an imitation trajectories folder (HuggingFace datasets, {len(eps)} rows with "
             f"{', '.join(fields)})")
    return {"episodes": eps, "notes": notes, "found": found, "episode_keys": [str(i) for i in range(len(eps))],
            "metadata": {}}


def _time_limited(infos: Any) -> bool:
    """Whether the last of a trajectory's info strings (JSON, as imitation writes them) records a time limit."""
    if not infos:
        return False
    try:
        last = json.loads(infos[-1])
    except (TypeError, ValueError):
        return False
    return isinstance(last, dict) and bool(last.get(TIME_LIMIT_KEY, False))


def read_imitation_transitions(arrays: Any) -> tuple[list[dict[str, Any]], list[str]]:
    """Trajectories from imitation's flattened transitions (`obs`, `acts`, `next_obs`, `dones`, optional `rews`).

    `arrays` is the importer's checked view of the file (`digail.data.array_files.Arrays`: `get`, `optional`,
    `where`). Returns the episodes (as `digail.data.importers.trajectories_from_episodes` takes them) and notes.
    """
    where = arrays.where
    obs, acts, next_obs = arrays.get("obs"), arrays.get("acts"), arrays.get("next_obs")
    dones = arrays.get("dones", kind="flag")
    rews = arrays.optional("rews")
    n = len(obs) if obs.ndim >= 1 else 0
    if n == 0:
        raise UserError(f"{where} holds no transitions; save at least one.")
    for name, arr in (("acts", acts), ("next_obs", next_obs), ("dones", dones), ("rews", rews)):
        if arr is not None and (arr.ndim < 1 or len(arr) != n):
            raise UserError(f"{where} has {len(arr) if arr.ndim else 'a scalar'} rows of '{name}' but {n} "
                            "observations; the arrays must have matching lengths.")
    if next_obs.shape[1:] != obs.shape[1:]:
        raise UserError(f"{where} has 'next_obs' of shape {next_obs.shape[1:]} per step but 'obs' of "
                        f"{obs.shape[1:]}; they must match.")
    # a trajectory ends on a done flag, or where the next row does not start from the state this one led to
    jumps = ~np.all(np.isclose(next_obs[:-1].reshape(n - 1, -1), obs[1:].reshape(n - 1, -1)), axis=1) \
        if n > 1 else np.zeros(0, bool)
    ends = np.flatnonzero(dones[:-1] | jumps) + 1
    bounds = list(zip([0, *ends.tolist()], [*ends.tolist(), n], strict=True))
    eps = [{"where": where, "obs": np.concatenate([obs[a:b], next_obs[b - 1:b]]), "acts": acts[a:b],
            "rews": None if rews is None else rews[a:b], "terminated": bool(dones[b - 1])} for a, b in bounds]
    unflagged = int(np.sum(jumps & ~dones[:-1]))
    notes = []
    if unflagged or not dones[-1]:
        notes.append(f"{unflagged + int(not dones[-1])} of {len(eps)} trajectories end without a 'dones' flag "
                     "(where 'next_obs' is not the next row's 'obs', or at the end of the file) and were kept as "
                     "truncated")
    return eps, notes
