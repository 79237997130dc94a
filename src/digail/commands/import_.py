"""`digail import SOURCE`: demonstrations from another tool (SB3, imitation, D4RL, robomimic, LeRobot, plain arrays)
as a Minari dataset.

The module is `import_` because `import` is a Python keyword; the subcommand is `digail import`.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Annotated, Literal

import tyro


@dataclass(frozen=True)
class ImportArgs:
    """Import demonstrations (SB3 / imitation .npz or folder, D4RL or robomimic HDF5, LeRobot dataset, arrays) as a
    Minari dataset digail reads."""

    source: Annotated[Path, tyro.conf.Positional]
    """the .npz or HDF5 file, or the imitation / LeRobot dataset folder, of demonstrations"""
    env: str = ""
    """environment the data was recorded in: checked against its spaces and stored, so that `digail train`,
    `evaluate` and `run` can make it (default: none; the spaces come from the data, enough to pre-train and
    segment)"""
    out: Path | None = None
    """output dataset folder (default: $MINARI_DATASETS_PATH/<dataset id>)"""
    format: Literal["auto", "sb3", "imitation", "d4rl", "arrays", "imitation-transitions", "imitation-dataset",
                    "robomimic", "lerobot"] = "auto"
    """layout of the source: sb3 (obs, actions, episode_starts), imitation (obs, acts, indices, terminal),
    imitation-transitions (obs, acts, next_obs, dones), d4rl (observations, actions, terminals, timeouts), arrays
    (observations, actions, episode_ends), imitation-dataset (the folder imitation.data.serialize.save writes),
    robomimic (data/demo_<n> groups), lerobot (meta/info.json, data/*.parquet); auto tells it from the source"""
    obs_keys: tuple[str, ...] | None = None
    """robomimic / LeRobot only: observation keys to flatten and join, in this order (default: robomimic's
    low-dimensional keys, sorted; LeRobot's observation.state)"""
    dataset_id: str | None = None
    """Minari id stored in the dataset (default: imported/<file name>-v0)"""
    force: bool = False
    """overwrite an existing output folder"""


def import_command(args: ImportArgs) -> Path:
    """Read the file, write the dataset; returns its folder."""
    from digail.data.importers import import_demonstrations

    path, imported = import_demonstrations(args.source, args.out, env_id=args.env or None, fmt=args.format,
                                           dataset_id=args.dataset_id, force=args.force, obs_keys=args.obs_keys)
    if imported.found:
        print(f"found {imported.found}")
    for note in imported.notes:
        print(f"note: {note}.")
    env = f" of {args.env}" if args.env else " (no environment: the spaces come from the data)"
    print(f"imported {len(imported.trajs)} episodes, {imported.num_steps} steps{env} from the {imported.fmt} layout "
          f"into {path}")
    return path
