"""`digail evaluate RUN`: closed-loop evaluation of a run's hierarchical policy into RUN/eval.json."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Annotated, Any

import tyro

from digail.checks import check_episodes
from digail.config import FINAL_EVAL_SEED, check_seed


@dataclass(frozen=True)
class EvaluateArgs:
    """Roll out a run's hierarchical policy (closed-loop macro-policy) and write eval.json."""

    run: Annotated[Path, tyro.conf.Positional]
    """run folder"""
    episodes: int | None = None
    """evaluation episodes (default: the env's preset's, paper: 300, Fetch 100 as its Table 2)"""
    seed: int = FINAL_EVAL_SEED
    """seed of the first evaluation episode"""
    stochastic: bool = False
    """sample actions from pi instead of taking its mean / most likely action (the default, as in SB3)"""
    video: bool = False
    """also record a video of the first episodes into RUN/videos"""
    env_arg: tuple[str, ...] = ()
    """KEY=VALUE keyword arguments for the env, e.g. order=3,2,1,0 for the landmark route in a new order (default:
    none, the env's own task; given, the return is not normalised by the expert's, which plays the default task)"""

    def __post_init__(self) -> None:
        check_episodes(self.episodes)
        check_seed(self.seed, count=self.episodes if self.episodes is not None else 300)  # the largest default
        if self.env_arg:
            from digail.envs.registry import parse_env_args

            parse_env_args(self.env_arg)  # a malformed one is refused before any work


def evaluate_command(args: EvaluateArgs) -> dict[str, Any]:
    """Write RUN/eval.json (and a video when asked); returns its content."""
    from digail.checkpoint import load_model
    from digail.commands.common import check_output_folder, print_eval_summary, run_env_id
    from digail.envs.registry import parse_env_args, preset_for
    from digail.eval.returns import evaluate
    from digail.fsio import run_dir_lock, write_json

    run = check_output_folder(args.run)
    with run_dir_lock(run):  # one writer per run folder
        model, meta = load_model(run / "model.pt")
        env_id = run_env_id(run, meta)
        episodes = args.episodes if args.episodes is not None else preset_for(env_id).eval_episodes
        result = evaluate(model, env_id, episodes, args.seed, not args.stochastic,
                          env_kwargs=parse_env_args(args.env_arg) or None)
        result["kind"] = meta.get("kind")
        write_json(run / "eval.json", result)
        print_eval_summary(result)
        if args.video:
            from digail.viz.video import record_video

            mp4, gif = record_video(model, env_id, run / "videos" / "eval.mp4", seed=args.seed,
                                    env_kwargs=parse_env_args(args.env_arg) or None)
            print(f"video: {mp4} and {gif}")
    return result
