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
    """one name per code for the exported annotations (default: code_0, code_1, ...)"""
    obs_keys: tuple[str, ...] | None = None
    """robomimic / LeRobot --demos only: the observation keys to read, as given to `digail import --obs-keys`"""
    force: bool = False
    """replace an existing --out"""


def segment_command(args: SegmentArgs) -> dict[str, Any]:
    """Segment with the run's macro-policy, write codes and scores into the run folder.

    Uses the run's training demonstrations (the `demos` entry of RUN/config.json) unless `args.demos` is given.
    Returns the metrics written to RUN/segmentation.json.
    """
    import numpy as np

    from digail.checkpoint import load_model, read_config
    from digail.commands.common import check_output_folder
    from digail.data.annotations import check_export, code_names, export_segmentation
    from digail.data.importers import is_import_source, prepare_import
    from digail.data.minari_io import load_dataset
    from digail.eval.segmentation import summary_line, write_segmentation
    from digail.fsio import run_dir_lock

    if args.export is None and (args.out is not None or args.names is not None):
        raise UserError("--out and --names go with --export; add --export robomimic, lerobot, csv or json.")
    run, demos = check_output_folder(args.run), args.demos
    with run_dir_lock(run):  # one writer per run folder
        model, meta = load_model(run)
        if demos is None:
            config = read_config(run) or meta["config"]
            demos = config.get("demos")
            if not demos:
                raise UserError(f"{run} does not record its demonstrations; pass --demos.")
        source: str | None
        source_format: str | None
        if is_import_source(demos):  # another tool's file, read as it is (no environment to check)
            imported = prepare_import(demos, obs_keys=args.obs_keys)
            for note in imported.notes:
                print(f"note: {note}.")
            trajs, source, source_format = imported.trajs, imported.source, imported.fmt
            episode_keys = imported.episode_keys
        else:
            if args.obs_keys:
                raise UserError(f"--obs-keys applies when --demos is a robomimic file or a LeRobot dataset; {demos} is "
                                "a Minari dataset, whose observations were chosen when it was imported, drop it.")
            dataset = load_dataset(demos)
            if meta.get("env_id") and dataset.env_id and dataset.env_id != meta["env_id"]:
                raise UserError(f"the model was trained on {meta['env_id']} but {demos} holds {dataset.env_id} "
                                "demonstrations; pass demonstrations of the model's environment.")
            record = dataset.metadata.get("digail") or {}
            trajs, source, source_format = dataset.trajs, record.get("imported_from"), record.get("format")
            episode_keys = record.get("episode_keys") or [str(i) for i in range(len(trajs))]
        if args.export is not None:
            names = code_names(model.codes, args.names)
            check_export(args.export, args.out, source, source_format, args.force)
        if args.label_map is not None:
            labels = {int(v) for t in trajs if t.subtasks is not None for v in set(t.subtasks.tolist())}
            if not labels:
                raise UserError(f"{demos} has no oracle labels to merge; drop --label-map.")
            if min(labels) < 0 or max(labels) >= len(args.label_map):
                raise UserError(f"--label-map gives {len(args.label_map)} labels but {demos} has labels "
                                f"{min(labels)} to {max(labels)}; give one number per oracle label.")
        metrics = write_segmentation(run, model, trajs, demos=str(demos), label_map=args.label_map)
        print(summary_line(metrics))
        print(f"wrote {run / 'segmentation.json'}, {run / 'codes.npz'} and {run / 'figures' / 'segmentation.png'}")
        if args.export is not None and args.out is not None:
            with np.load(run / "codes.npz") as stored:
                codes = [stored[k] for k in sorted(stored.files)]
            path = export_segmentation(args.export, args.out, episode_keys, codes, names, source=source,
                                       force=args.force)
            print(f"wrote the segmentation as {args.export} annotations ({', '.join(names)}) to {path}")
    return metrics
