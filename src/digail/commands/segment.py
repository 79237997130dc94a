"""`digail segment RUN`: segment demonstrations with a run's macro-policy, score them, and write the segmentation
back as sub-task annotations (`--export`)."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Annotated, Any, Literal

import tyro

from digail.errors import UserError


@dataclass(frozen=True)
class SegmentArgs:
    """Segment demonstrations with a run's macro-policy and score against oracle labels where present."""

    run: Annotated[Path, tyro.conf.Positional]
    """run folder holding a VAE or trained policy"""
    demos: str | None = None
    """dataset to segment (default: the run's training demonstrations); also a file or folder `digail import`
    reads (robomimic, LeRobot, imitation, ...), read as it is"""
    label_map: tuple[int, ...] | None = None
    """score against merged oracle labels: label l counts as the l-th number (Fetch pick / place from the four
    phases: `--label-map 0 0 1 1`)"""
    export: Literal["robomimic", "lerobot", "csv", "json"] | None = None
    """also write the segmentation to --out: robomimic (a copy of the robomimic source with MimicGen's
    datagen_info/subtask_term_signals/<name>), lerobot (a copy of the LeRobot dataset with a subtask_index column
    and meta/subtasks.parquet), csv or json (a table of segments: episode, start, end, code, name)"""
    out: Path | None = None
    """the file or folder --export writes (never the input)"""
    names: tuple[str, ...] | None = None
    """one name per code for the exported annotations, in the order the demonstrations take the sub-tasks (the
    first name goes to the code that comes first, whatever its number; default: code_0, code_1, ...)"""
    obs_keys: tuple[str, ...] | None = None
    """robomimic / LeRobot --demos only: the observation keys to read, as given to `digail import --obs-keys`
    (default: the keys the run's dataset was imported with, in that order)"""
    force: bool = False
    """replace an existing --out"""
    reading: Literal["offline", "causal"] = "offline"
    """which codes to write and export: `offline`, the code path that best explains each whole demonstration under
    the macro-policy and the sub-task policies (for annotations), or `causal`, what the macro-policy decides step
    by step in closed loop (the paper's q); segmentation.json scores both"""


def segment_command(args: SegmentArgs) -> dict[str, Any]:
    """Segment with the run's macro-policy, write codes and scores into the run folder.

    Uses the run's training demonstrations (the `demos` entry of RUN/config.json) unless `args.demos` is given.
    Everything the command refuses is refused before the run folder is written: the export's `--out` (never the
    input, the run or its dataset; `digail.data.annotations.check_export`) and observation keys in another order
    than the run was trained on. Returns the metrics written to RUN/segmentation.json.
    """
    from digail.algos.decode import read_codes
    from digail.checkpoint import load_model, read_config
    from digail.commands.common import check_output_folder
    from digail.data.annotations import check_export, code_names, export_segmentation
    from digail.data.importers import is_import_source, prepare_import
    from digail.data.minari_io import load_dataset
    from digail.data.subtask_plan import names_by_code
    from digail.errors import OldOutputLeft
    from digail.eval.segmentation import summary_line, write_segmentation
    from digail.fsio import run_dir_lock

    if args.export is None and (args.out is not None or args.names is not None):
        raise UserError("--out and --names go with --export; add --export robomimic, lerobot, csv or json.")
    run, demos = check_output_folder(args.run), args.demos
    left: OldOutputLeft | None = None
    with run_dir_lock(run):  # one writer per run folder
        model, meta = load_model(run)
        config = read_config(run) or meta["config"]
        trained_on = config.get("demos")
        if demos is None:
            demos = trained_on
            if not demos:
                raise UserError(f"{run} does not record its demonstrations; pass --demos.")
        run_dataset, run_keys, run_format = _run_dataset(trained_on)
        import_source = is_import_source(demos)
        source, source_format, record = _source_of(demos, import_source)
        # the run's order applies to sources of the layout its dataset was imported from
        obs_keys = _obs_keys(args.obs_keys, run_keys if run_format == source_format else None, demos, import_source,
                             record)
        names: list[str] = []
        if args.export is not None:  # before anything is read or written
            names = code_names(model.codes, args.names)
            protected = [(run, "the run folder")]
            if run_dataset is not None:
                protected.append((run_dataset, "the run's dataset"))
            if not import_source:
                protected.append((record["folder"], "the input"))
            check_export(args.export, args.out, source, source_format, args.force, protected=protected)
        if import_source:  # another tool's file, read as it is (no environment to check)
            imported = prepare_import(demos, obs_keys=obs_keys)
            for note in imported.notes:
                print(f"note: {note}.")
            trajs, episode_keys = imported.trajs, imported.episode_keys
        else:
            dataset = load_dataset(demos)
            if meta.get("env_id") and dataset.env_id and dataset.env_id != meta["env_id"]:
                raise UserError(f"the model was trained on {meta['env_id']} but {demos} holds {dataset.env_id} "
                                "demonstrations; pass demonstrations of the model's environment.")
            trajs = dataset.trajs
            episode_keys = record.get("episode_keys") or [str(i) for i in range(len(trajs))]
        if args.label_map is not None:
            labels = {int(v) for t in trajs if t.subtasks is not None for v in set(t.subtasks.tolist())}
            if not labels:
                raise UserError(f"{demos} has no oracle labels to merge; drop --label-map.")
            if min(labels) < 0 or max(labels) >= len(args.label_map):
                raise UserError(f"--label-map gives {len(args.label_map)} labels but {demos} has labels "
                                f"{min(labels)} to {max(labels)}; give one number per oracle label.")
        codes = read_codes(model, trajs, args.reading)
        if args.names:  # given in the demonstrated order
            names = names_by_code(names, codes)
        if args.export is not None and args.out is not None:
            # written before the run folder: a refusal the export finds only in the source (a clash of names, a
            # column already there, a frame gap) leaves the run's segmentation as it was
            notes: list[str] = []
            try:
                path = export_segmentation(args.export, args.out, episode_keys, codes, names, source=source,
                                           force=args.force, notes=notes, reading=args.reading)
            except OldOutputLeft as exc:  # the export is in place: the run's segmentation is written as well
                left, path = exc, Path(args.out)
            for note in notes:
                print(f"note: {note}.")
            print(f"wrote the segmentation as {args.export} annotations ({', '.join(args.names or names)}) to {path}")
        metrics = write_segmentation(run, model, trajs, demos=str(demos), label_map=args.label_map, codes=codes,
                                     reading=args.reading)
        print(summary_line(metrics))
        print(f"wrote {run / 'segmentation.json'}, {run / 'codes.npz'} and {run / 'figures' / 'segmentation.png'}")
    if left is not None:
        raise UserError(left.sentence(f"the new {left.final} and the run's segmentation are in place"))
    return metrics


def _run_dataset(trained_on: str | None) -> tuple[Path | None, list[str] | None, str | None]:
    """The folder of the dataset a run was trained on, the observation keys it was imported with (robomimic and
    LeRobot sources) and the layout it was imported from, each None where unknown (no record, or the dataset is
    gone)."""
    from digail.data.minari_io import dataset_metadata

    if not trained_on:
        return None, None, None
    try:
        folder, metadata = dataset_metadata(trained_on)
    except UserError:  # moved or deleted since: nothing to protect or compare with
        return (Path(trained_on) if Path(trained_on).exists() else None), None, None
    record = metadata.get("digail") or {}
    keys = (record.get("source_metadata") or {}).get("obs_keys")
    return folder, [str(k) for k in keys] if isinstance(keys, list) and keys else None, record.get("format")


def _source_of(demos: str, import_source: bool) -> tuple[str | None, str | None, dict[str, Any]]:
    """Where the demonstrations come from, known before they are read: the file or folder another tool wrote and
    its layout, and for a Minari dataset digail's record of its import (with `folder`: the dataset's folder)."""
    from digail.data.formats import detect
    from digail.data.minari_io import dataset_metadata

    if import_source:
        return str(demos), detect(Path(demos)) or "named-array", {}
    folder, metadata = dataset_metadata(demos)
    record = dict(metadata.get("digail") or {})
    record["folder"] = folder
    return record.get("imported_from"), record.get("format"), record


def _obs_keys(given: tuple[str, ...] | None, run_keys: list[str] | None, demos: str, import_source: bool,
              record: dict[str, Any]) -> list[str] | None:
    """The observation keys to read, in the order the run was trained on: the run's own when none are given;
    refused when the given keys, or a dataset's imported ones, are another order or another set."""
    if not import_source:
        if given:
            raise UserError(f"--obs-keys applies when --demos is a robomimic file or a LeRobot dataset; {demos} is "
                            "a Minari dataset, whose observations were chosen when it was imported, drop it.")
        keys = (record.get("source_metadata") or {}).get("obs_keys")
        if run_keys and isinstance(keys, list) and keys and [str(k) for k in keys] != run_keys:
            raise UserError(f"{demos} was imported with observation keys {', '.join(map(str, keys))} but the run was "
                            f"trained on {', '.join(run_keys)}, in this order; import it again with --obs-keys "
                            f"{' '.join(run_keys)}.")
        return None
    if given and run_keys and list(given) != run_keys:
        raise UserError(f"--obs-keys {' '.join(given)} is not what the run was trained on: {' '.join(run_keys)}, in "
                        f"this order (each key is a block of the observation the model reads); pass --obs-keys "
                        f"{' '.join(run_keys)} or drop it.")
    return list(given) if given else run_keys
