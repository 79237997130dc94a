"""`digail compose RUN --schedule S`: the sub-task policies under a code schedule instead of the macro-policy."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Annotated, Any

import tyro

from digail.config import check_at_least, check_seed


@dataclass(frozen=True)
class ComposeArgs:
    """Run the sub-task policies under a code schedule instead of the learned macro-policy."""

    run: Annotated[Path, tyro.conf.Positional]
    """run folder of a trained policy"""
    schedule: str = "1:60,0:60"
    """code:steps pairs, e.g. '1:60,0:60' (Circle-World reversed circles when code 1 is the counter-clockwise one:
    code ids are arbitrary, `mapping` in the run's segmentation.json says which code matched which sub-task)"""
    episodes: int = 100
    """episodes to roll out"""
    seed: int = 20_000
    """seed of the first episode"""

    def __post_init__(self) -> None:
        check_at_least(self.episodes, "--episodes")
        check_seed(self.seed, count=self.episodes)


def compose_command(args: ComposeArgs) -> dict[str, Any]:
    """Write RUN/compose.json and RUN/figures/compose.png; returns the summary."""
    import numpy as np

    from digail.checkpoint import load_model
    from digail.commands.common import check_output_folder, print_eval_summary, run_env_id
    from digail.eval.composition import compose, episode_limit, parse_schedule
    from digail.utils import run_dir_lock, write_json
    from digail.viz.run_figures import composition_figure

    run = check_output_folder(args.run)
    with run_dir_lock(run):  # one writer per run folder
        model, meta = load_model(run / "model.pt")
        env_id = run_env_id(run, meta)
        pairs = parse_schedule(args.schedule, model.codes, episode_limit(env_id))
        result, eps = compose(model, env_id, pairs, args.episodes, args.seed)
        result["schedule"] = args.schedule
        fig = composition_figure([(np.asarray(e.obs), np.asarray(e.codes)) for e in eps],
                                 run / "figures" / "compose.png", args.schedule)
        result["figure"] = str(fig)
        write_json(run / "compose.json", result)
        print_eval_summary(result)
    return result
