"""`digail demos ENV`: record expert demonstrations as a Minari dataset."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Annotated

import tyro

from digail.checks import check_episodes
from digail.config import check_seed


@dataclass(frozen=True)
class DemosArgs:
    """Record expert demonstrations as a Minari dataset (oracle labels kept under infos['subtask'])."""

    env: Annotated[str, tyro.conf.Positional]
    """environment id, e.g. digail/CircleWorld-v0"""
    episodes: int | None = None
    """number of episodes (default: the paper's size for this env)"""
    out: Path | None = None
    """output dataset folder (default: $MINARI_DATASETS_PATH/<dataset id>)"""
    seed: int = 0
    """seed of the first episode; episode i uses seed + i"""
    expert: Path | None = None
    """RL expert checkpoint for MuJoCo envs (default: the shipped one)"""
    force: bool = False
    """overwrite an existing output folder"""

    def __post_init__(self) -> None:
        check_episodes(self.episodes)
        check_seed(self.seed, count=self.episodes or 1)


def demos_command(args: DemosArgs) -> Path:
    """Record the demonstrations; returns the dataset folder."""
    from digail.data.demos import record_demos

    path = record_demos(args.env, episodes=args.episodes, out=args.out, seed=args.seed,
                        expert=args.expert, force=args.force)
    print(f"wrote demonstrations to {path}")
    return path
