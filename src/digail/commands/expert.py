"""`digail expert ENV`: train a Stable-Baselines3 expert (checkpoints, resume, final evaluation)."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Annotated

import tyro

from digail.config import check_at_least, check_seed
from digail.errors import UserError

EXPERT_STEPS_MAX = 10**9
"""most environment steps of one expert training (`--steps`): over 300 times the largest budget of a recipe (3M),
so a slip of the keyboard is one sentence rather than a training that never ends"""

@dataclass(frozen=True)
class ExpertArgs:
    """Train a Stable-Baselines3 expert for a MuJoCo / classic-control env (checkpoints, resume)."""

    env: Annotated[str, tyro.conf.Positional]
    """environment id: Pendulum-v1, InvertedPendulum-v5, Hopper-v5, Walker2d-v5"""
    out: Path | None = None
    """expert folder (default: experts_work/<env>)"""
    steps: int | None = None
    """environment steps (default: the env's budget)"""
    resume: bool = False
    """continue from the folder's last checkpoint"""
    seed: int = 0
    """random seed"""
    device: str = "cpu"
    """torch device for SB3"""

    def __post_init__(self) -> None:
        check_at_least(self.steps, "--steps")
        if self.steps is not None and self.steps > EXPERT_STEPS_MAX:
            raise UserError(f"--steps must be at most {EXPERT_STEPS_MAX:,}, got {self.steps}.")
        check_seed(self.seed)


def expert_command(args: ExpertArgs) -> Path:
    """Train (or resume) the expert into its folder; returns the folder."""
    from digail.experts.rl import ExpertRun, train_expert

    return train_expert(ExpertRun(env=args.env, out=args.out, steps=args.steps, resume=args.resume,
                                  seed=args.seed, device=args.device))
