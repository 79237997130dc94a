"""`digail segment RUN`: segment demonstrations with a run's macro-policy and score them."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Annotated, Any

import tyro

from digail.errors import UserError


@dataclass(frozen=True)
class SegmentArgs:
    """Segment demonstrations with a run's macro-policy and score against oracle labels where present."""

    run: Annotated[Path, tyro.conf.Positional]
    """run folder holding a VAE or trained policy"""
    demos: str | None = None
    """dataset to segment (default: the run's training demonstrations)"""
    label_map: tuple[int, ...] | None = None
    """score against merged oracle labels: label l counts as the l-th number (Fetch pick / place from the four
    phases: `--label-map 0 0 1 1`)"""


def segment_command(args: SegmentArgs) -> dict[str, Any]:
    """Segment with the run's macro-policy, write codes and scores into the run folder.

    Uses the run's training demonstrations (the `demos` entry of RUN/config.json) unless `args.demos` is given.
    Returns the metrics written to RUN/segmentation.json.
    """
    from digail.checkpoint import load_model, read_config
    from digail.commands.common import check_output_folder
    from digail.data.minari_io import load_dataset
    from digail.eval.segmentation import summary_line, write_segmentation
    from digail.utils import run_dir_lock

    run, demos = check_output_folder(args.run), args.demos
    with run_dir_lock(run):  # one writer per run folder
        model, meta = load_model(run)
        if demos is None:
            config = read_config(run) or meta["config"]
            demos = config.get("demos")
            if not demos:
                raise UserError(f"{run} does not record its demonstrations; pass --demos.")
        dataset = load_dataset(demos)
        if meta.get("env_id") and dataset.env_id and dataset.env_id != meta["env_id"]:
            raise UserError(f"the model was trained on {meta['env_id']} but {demos} holds {dataset.env_id} "
                            "demonstrations; pass demonstrations of the model's environment.")
        if args.label_map is not None:
            labels = {int(v) for t in dataset.trajs if t.subtasks is not None for v in set(t.subtasks.tolist())}
            if not labels:
                raise UserError(f"{demos} has no oracle labels to merge; drop --label-map.")
            if min(labels) < 0 or max(labels) >= len(args.label_map):
                raise UserError(f"--label-map gives {len(args.label_map)} labels but {demos} has labels "
                                f"{min(labels)} to {max(labels)}; give one number per oracle label.")
        metrics = write_segmentation(run, model, dataset.trajs, demos=str(demos), label_map=args.label_map)
        print(summary_line(metrics))
        print(f"wrote {run / 'segmentation.json'}, {run / 'codes.npz'} and {run / 'figures' / 'segmentation.png'}")
    return metrics
