"""`digail segment RUN`: segment demonstrations with a run's macro-policy and score them."""

from __future__ import annotations

import json
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


def segment_command(args: SegmentArgs) -> dict[str, Any]:
    """Segment with the run's macro-policy, write codes and scores into the run folder.

    Uses the run's training demonstrations (the `demos` entry of RUN/config.json) unless `args.demos` is given.
    Returns the metrics written to RUN/segmentation.json.
    """
    from digail.checkpoint import CONFIG_FILE, load_model
    from digail.data.minari_io import load_dataset
    from digail.eval.segmentation import summary_line, write_segmentation

    run, demos = Path(args.run), args.demos
    if not run.is_dir():
        raise UserError(f"run folder {run} does not exist; pass a folder made by `digail pretrain` or `digail train`.")
    model, meta = load_model(run)
    if demos is None:
        config_path = run / CONFIG_FILE
        config = meta["config"]
        if config_path.is_file():
            try:
                config = json.loads(config_path.read_text())
            except json.JSONDecodeError as exc:
                raise UserError(f"{config_path} is not valid JSON ({exc}); pass --demos explicitly.") from exc
        demos = config.get("demos")
        if not demos:
            raise UserError(f"{run} does not record its demonstrations; pass --demos.")
    dataset = load_dataset(demos)
    if meta.get("env_id") and dataset.env_id and dataset.env_id != meta["env_id"]:
        raise UserError(f"the model was trained on {meta['env_id']} but {demos} holds {dataset.env_id} "
                        "demonstrations; pass demonstrations of the model's environment.")
    metrics = write_segmentation(run, model, dataset.trajs, demos=str(demos))
    print(summary_line(metrics))
    print(f"wrote {run / 'segmentation.json'}, {run / 'codes.npz'} and {run / 'figures' / 'segmentation.png'}")
    return metrics
