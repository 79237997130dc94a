"""LeRobot datasets (format v3.0, and v2.1's per-episode files), read and annotated with pyarrow alone.

The layout: `meta/info.json` (the features: name -> dtype and shape; `codebase_version`, `fps`), the frames in
Parquet files below `data/` (v3.0: `data/chunk-000/file-000.parquet`, several episodes a file), one row per frame
with the feature columns and `episode_index`, `frame_index`, `index`, `task_index`; `meta/episodes/`,
`meta/tasks.parquet`, `meta/stats.json`; camera frames as videos below `videos/` or images.

Reading: the observation is `observation.state`, or the chosen keys flattened and joined in the order given
(default without `observation.state`: every numeric `observation.*` feature, sorted); the action is `action`;
`next.reward` becomes the reward. Videos and images are never opened. Episodes are told apart by
`episode_index` and ordered by `frame_index`. A row holds a state and the action taken in it, never the state
after the last action, so each episode's last action is dropped and the episode kept as truncated. A
`subtask_index` column (what `write_subtask_index` adds) becomes the oracle labels.

Writing (`write_subtask_index`): a copy of the dataset with a per-frame `subtask_index` column (declared in
`meta/info.json`) and the table of names `meta/subtasks.parquet` (index: the name, column `subtask_index`, as
`meta/tasks.parquet` is laid out). The input folder is never written.
"""

from __future__ import annotations

import json
import shutil
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from digail.data.input_files import as_float32, check_tree, inside, read_json
from digail.errors import UserError
from digail.fsio import atomic_dir, make_writable
from digail.utils import one_line

SUBTASK_COLUMN = "subtask_index"
"""the per-frame column of sub-task indices (into `meta/subtasks.parquet`)"""
SUBTASKS_TABLE = "meta/subtasks.parquet"
"""the table of sub-task names, laid out as LeRobot's `meta/tasks.parquet`"""
DIGAIL_KEY = b"digail"
"""the schema-metadata key of `SUBTASKS_TABLE` that marks the column as digail's own export: a segmentation, which
a later reading does not take for oracle labels"""
_NON_NUMERIC = ("image", "video", "string")


def is_lerobot(path: str | Path) -> bool:
    """Whether `path` is a LeRobot dataset folder (it has `meta/info.json`)."""
    path = Path(path)
    return path.is_dir() and (path / "meta" / "info.json").is_file()


def _info(path: Path) -> dict[str, Any]:
    info = read_json(inside(path, "meta/info.json", str(path)), "the LeRobot dataset")
    if not isinstance(info, dict) or not isinstance(info.get("features"), dict):
        raise UserError(f"{path / 'meta' / 'info.json'} has no 'features' table; it is not a LeRobot dataset's "
                        "info.json.")
    return info


def _digail_subtasks(path: Path) -> bool:
    """Whether the dataset's `subtask_index` column is digail's own export (its names table says so)."""
    import pyarrow as pa
    import pyarrow.parquet as pq

    if not (path / SUBTASKS_TABLE).exists():
        return False
    table = inside(path, SUBTASKS_TABLE, str(path), "names table")
    try:
        return DIGAIL_KEY in (pq.read_schema(table).metadata or {})
    except (OSError, pa.ArrowInvalid) as exc:
        raise UserError(f"cannot read {table} as Parquet ({one_line(exc)}); the file is damaged.") from None


def data_files(path: Path) -> list[Path]:
    """The dataset's frame files (`data/**/*.parquet`), in name order."""
    files = sorted((path / "data").rglob("*.parquet"))
    if not files:
        raise UserError(f"{path} has meta/info.json but no Parquet files below data/; copy the whole LeRobot "
                        "dataset folder.")
    # each a regular file inside the dataset (a FIFO would block the reader for ever, a link could lead anywhere)
    return [inside(path, str(f.relative_to(path)), str(path), "frame file") for f in files]



def _column(table: Any, name: str, where: str) -> np.ndarray:
    """A feature column as a (rows, d) array (list columns flattened per row) or (rows,) for scalars."""
    import pyarrow as pa

    col = table.column(name).combine_chunks()
    if col.null_count:
        raise UserError(f"{where} has {col.null_count} empty (null) value{'s' if col.null_count > 1 else ''} in "
                        f"'{name}'; every frame needs one.")
    leaf = col.type
    while pa.types.is_fixed_size_list(leaf) or pa.types.is_list(leaf) or pa.types.is_large_list(leaf):
        leaf = leaf.value_type
    if not (pa.types.is_integer(leaf) or pa.types.is_floating(leaf) or pa.types.is_boolean(leaf)):
        raise UserError(f"{where} has '{name}' of type {col.type}, which is not numeric; choose numeric features.")
    if pa.types.is_fixed_size_list(col.type) or pa.types.is_list(col.type) or pa.types.is_large_list(col.type):
        if not pa.types.is_fixed_size_list(col.type) and len(col):
            lengths = col.value_lengths().to_numpy(zero_copy_only=False)
            if lengths.min() != lengths.max():  # a reshape would mix neighbouring frames' values
                raise UserError(f"{where} has '{name}' rows of different lengths ({int(lengths.min())} to "
                                f"{int(lengths.max())} values); each frame needs the same size.")
        values = col.flatten()
        while isinstance(values, pa.ListArray | pa.LargeListArray | pa.FixedSizeListArray):
            values = values.flatten()
        values = values.to_numpy(zero_copy_only=False)
        return values.reshape(len(col), -1)
    return col.to_numpy(zero_copy_only=False)


def read_lerobot(path: str | Path, obs_keys: Sequence[str] | None = None) -> dict[str, Any]:
    """Demonstrations of a LeRobot dataset folder; see the module docstring.

    Args:
        path: the dataset folder (the one holding `meta/` and `data/`).
        obs_keys: features to flatten and join as the observation, in this order (default: `observation.state`,
            else every numeric `observation.*` feature, sorted).

    Returns:
        A dict with `episodes` (per episode its arrays, as `digail.data.importers.trajectories_from_episodes`
        takes them), `notes`, `found`, `episode_keys` (the episode indices) and `metadata`, which
        `digail.data.importers.read_demonstrations` checks and turns into an `Imported`.

    Raises:
        UserError: missing features or columns, video features asked for, episodes of one frame only.
    """
    import pyarrow as pa
    import pyarrow.parquet as pq

    path = Path(path)
    where = str(path)
    info = _info(path)
    features: dict[str, Any] = info["features"]
    numeric = [k for k, v in features.items() if isinstance(v, dict) and v.get("dtype") not in _NON_NUMERIC]
    cameras = [k for k in features if k not in numeric]
    if obs_keys:
        for key in obs_keys:
            if key not in features:
                raise UserError(f"{where} has no feature '{key}'; its features are {', '.join(features)}.")
            if key in cameras:
                raise UserError(f"{where} has '{key}' as {features[key].get('dtype')} frames, which digail does not "
                                "read; choose numeric features such as observation.state.")
        chosen = list(obs_keys)
    elif "observation.state" in features:
        chosen = ["observation.state"]
    else:
        chosen = sorted(k for k in numeric if k.startswith("observation."))
        if not chosen:
            raise UserError(f"{where} has no numeric observation feature ({', '.join(features)}); name the keys to "
                            "read with --obs-keys.")
    if "action" not in features:
        raise UserError(f"{where} has no 'action' feature (it has {', '.join(features)}); digail needs the actions.")
    wanted = [*chosen, "action", "episode_index", "frame_index"]
    ours = SUBTASK_COLUMN in features and _digail_subtasks(path)
    optional = [c for c in ("next.reward", SUBTASK_COLUMN) if c in features and not (c == SUBTASK_COLUMN and ours)]
    tables = []
    for file in data_files(path):
        try:
            schema_names = pq.read_schema(file).names
            missing = [c for c in wanted if c not in schema_names]
            if missing:
                raise UserError(f"{file} has no column {missing[0]!r}, which {path / 'meta' / 'info.json'} "
                                "declares; the dataset is damaged.")
            tables.append(pq.read_table(file, columns=wanted + [c for c in optional if c in schema_names]))
        except (OSError, pa.ArrowInvalid) as exc:
            raise UserError(f"cannot read {file} as Parquet ({one_line(exc)}); the file is damaged.") from exc
    try:
        table = pa.concat_tables(tables, promote_options="default") if len(tables) > 1 else tables[0]
    except (pa.ArrowInvalid, pa.ArrowTypeError) as exc:
        raise UserError(f"{where} has frame files whose columns do not agree ({one_line(exc)}); the dataset is "
                        "damaged.") from None
    if not table.num_rows:
        raise UserError(f"{where} holds no frames (its Parquet files have no rows); copy the whole dataset.")
    episode = _column(table, "episode_index", where).reshape(-1).astype(np.int64)
    frame = _column(table, "frame_index", where).reshape(-1).astype(np.int64)
    order = np.lexsort((frame, episode))
    obs = np.concatenate([as_float32(_column(table, k, where).reshape(table.num_rows, -1), where, k)
                          for k in chosen], axis=1)[order]
    acts = _column(table, "action", where).reshape(table.num_rows, -1)[order]
    rews = _column(table, "next.reward", where).reshape(-1)[order] if "next.reward" in table.column_names else None
    labels = (_column(table, SUBTASK_COLUMN, where).reshape(-1)[order].astype(np.int64)
              if SUBTASK_COLUMN in table.column_names else None)
    episode = episode[order]
    starts = np.flatnonzero(np.diff(np.concatenate([[-1], episode])) != 0)
    ends = [*starts[1:].tolist(), len(episode)]
    _check_frames(frame[order], episode, starts, where)
    eps, keys, short = [], [], 0
    for a, b in zip(starts.tolist(), ends, strict=True):
        if b - a < 2:
            short += 1
            continue
        eps.append({"where": f"{where}, episode {episode[a]}", "obs": obs[a:b], "acts": acts[a:b - 1],
                    "acts_name": "action", "rews": None if rews is None else rews[a:b - 1], "terminated": False,
                    "subtasks": None if labels is None else labels[a:b]})
        keys.append(str(int(episode[a])))
    if not eps:
        raise UserError(f"{where} holds no episode of two frames or more; digail needs a state after each action.")
    notes = [f"LeRobot frames hold no state after an episode's last action, so the last action of each of "
             f"{len(eps)} episodes was dropped and the episodes kept as truncated"]
    if short:
        notes.append(f"{short} episodes of a single frame were skipped")
    if cameras:
        notes.append(f"camera features not read: {', '.join(cameras)}")
    if labels is not None:
        notes.append(f"oracle sub-task labels read from the '{SUBTASK_COLUMN}' column")
    elif ours:
        notes.append(f"the '{SUBTASK_COLUMN}' column is a segmentation digail exported, not read as oracle labels")
    version = info.get("codebase_version", "unknown")
    found = (f"a LeRobot dataset (format {version}, {len(eps)} episodes, {table.num_rows} frames; observation "
             f"{' + '.join(chosen)}, action 'action')")
    metadata = {"obs_keys": chosen, "lerobot": {k: info[k] for k in ("codebase_version", "fps", "robot_type")
                                                if k in info}}
    return {"episodes": eps, "notes": notes, "found": found, "episode_keys": keys, "metadata": metadata}


def _check_frames(frame: np.ndarray, episode: np.ndarray, starts: np.ndarray, where: str) -> None:
    """Refuse, in one sentence, an episode whose `frame_index` does not run 0, 1, 2, ... (rows sorted by episode
    and frame, `starts` the first row of each episode): a missing frame would join the states on either side as
    one step, and a repeated one would be read twice."""
    due = np.arange(len(frame)) - np.repeat(starts, np.diff(np.append(starts, len(frame))))
    bad = np.flatnonzero(frame != due)
    if not bad.size:
        return
    i = int(bad[0])
    ep, got, want = int(episode[i]), int(frame[i]), int(due[i])
    what = (f"starts at frame_index {got}, not 0" if want == 0 else
            f"skips frame_index {want} (it goes from {want - 1} to {got})" if got > want else
            f"has frame_index {got} twice")
    raise UserError(f"episode {ep} of {where} {what}; digail reads whole episodes whose frames are numbered 0, 1, "
                    "2, ... in turn, so give it the episode's every frame.")


def write_subtask_index(source: str | Path, out: str | Path, episode_keys: Sequence[str],
                        codes: Sequence[np.ndarray], names: Sequence[str], *, force: bool = False,
                        reading: str = "causal") -> Path:
    """Copy the LeRobot dataset `source` to `out` with a per-frame `subtask_index` column and its names table.

    Args:
        source: the dataset folder the demonstrations were read from (only read).
        out: the annotated copy (written into a temporary sibling folder, renamed at the end).
        episode_keys: the `episode_index` of each entry of `codes` (as `read_lerobot` lists them).
        codes: per episode, one code per action read (the frames but the last); the last frame takes the code
            before it. Frames of episodes not listed get -1.
        names: the name of each code, row k of `meta/subtasks.parquet` for code k.
        force: replace an existing `out`.
        reading: which reading of the segmentation the codes are (`digail.algos.decode.READINGS`), kept in the
            names table's schema metadata under `digail_reading`.

    Raises:
        UserError: `out` is the source or inside it, exists without `force`, the dataset already has a
            `subtask_index` column, codes that do not fit an episode.
    """
    import pyarrow as pa
    import pyarrow.parquet as pq

    source, out = Path(source), Path(out)
    if out.resolve() == source.resolve() or source.resolve() in out.resolve().parents:
        raise UserError(f"--out {out} is the input dataset or inside it; digail never modifies its input, choose "
                        "another --out.")
    info = _info(source)
    if SUBTASK_COLUMN in info["features"]:
        raise UserError(f"{source} already has a '{SUBTASK_COLUMN}' feature; export from a dataset without one.")
    by_episode = {}
    for key, demo_codes in zip(episode_keys, codes, strict=True):
        demo_codes = np.asarray(demo_codes, dtype=np.int64).reshape(-1)
        by_episode[int(key)] = np.concatenate([demo_codes, demo_codes[-1:]])
    check_tree(source)  # no FIFO to block the copy, no link to copy another folder's files from
    with atomic_dir(out, force=force) as tmp:
        shutil.copytree(source, tmp, dirs_exist_ok=True)
        make_writable(tmp)  # a read-only source's modes come with the copy, which is written and may be removed
        for file in data_files(tmp):
            table = pq.read_table(file)
            episode = table.column("episode_index").to_numpy().astype(np.int64)
            frame = table.column("frame_index").to_numpy().astype(np.int64)
            column = np.full(len(episode), -1, dtype=np.int64)
            for ep in np.unique(episode):
                rows = np.flatnonzero(episode == ep)
                ep_codes = by_episode.get(int(ep))
                if ep_codes is None:
                    continue
                if frame[rows].max() + 1 != len(ep_codes) or len(rows) > len(ep_codes):
                    raise UserError(f"episode {ep} of {source} has {frame[rows].max() + 1} frames but the "
                                    f"segmentation gives {len(ep_codes)}; segment the episodes read from this "
                                    "dataset.")
                column[rows] = ep_codes[frame[rows]]
            table = table.append_column(pa.field(SUBTASK_COLUMN, pa.int64()), pa.array(column))
            table = table.replace_schema_metadata(_hf_metadata(table.schema.metadata))
            pq.write_table(table, file)
        info["features"][SUBTASK_COLUMN] = {"dtype": "int64", "shape": [1], "names": None}
        (tmp / "meta" / "info.json").write_text(json.dumps(info, indent=4) + "\n")
        names_table = pa.table({"subtask_index": pa.array(range(len(names)), pa.int64()),
                                "subtask": pa.array(list(names), pa.string())})
        # pandas' index, as LeRobot's tasks table keeps its names: the name column is the index
        pandas_meta = {"index_columns": ["subtask"], "column_indexes": [], "columns": [
            {"name": "subtask_index", "field_name": "subtask_index", "pandas_type": "int64", "numpy_type": "int64",
             "metadata": None},
            {"name": "subtask", "field_name": "subtask", "pandas_type": "unicode", "numpy_type": "object",
             "metadata": None}], "pandas_version": "2.2.0"}
        names_table = names_table.replace_schema_metadata({b"pandas": json.dumps(pandas_meta).encode(),
                                                           DIGAIL_KEY: b"segmentation",
                                                           b"digail_reading": reading.encode()})
        pq.write_table(names_table, tmp / SUBTASKS_TABLE)
    return out


def _hf_metadata(metadata: dict[bytes, bytes] | None) -> dict[bytes, bytes]:
    """The HuggingFace `datasets` schema record of a frame file, with the new column declared (int64)."""
    metadata = dict(metadata or {})
    raw = metadata.get(b"huggingface")
    if raw is None:
        return metadata
    try:
        record = json.loads(raw)
        record["info"]["features"][SUBTASK_COLUMN] = {"dtype": "int64", "_type": "Value"}
    except (ValueError, KeyError, TypeError):
        return metadata  # an unknown record is left as it is; LeRobot takes the features from info.json
    metadata[b"huggingface"] = json.dumps(record).encode()
    return metadata
