"""`digail video RUN [--episodes N] [--schedule S]`: MP4 and GIF of a run's policy, code and step on every frame."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Annotated, Literal

import tyro

from digail.checks import VIDEO_EPISODES_MAX, check_episodes
from digail.config import FINAL_EVAL_SEED, check_at_least, check_seed
from digail.errors import UserError
from digail.fsio import check_writable, run_dir_lock


@dataclass(frozen=True)
class VideoArgs:
    """Render episodes of a run's policy (closed-loop, or under a code schedule) to RUN/videos as MP4 and GIF."""

    run: Annotated[Path, tyro.conf.Positional]
    """run folder of a trained policy (holding model.pt)"""
    episodes: int = 1
    """episodes to render, one after the other in one video"""
    schedule: str | None = None
    """code:steps pairs such as '1:60,0:60' to compose sub-task policies (default: the closed-loop macro-policy)"""
    seed: int = FINAL_EVAL_SEED
    """seed of the first episode (the evaluation seeds by default)"""
    max_steps: int | None = None
    """cut each episode after this many steps (default: play it to its end)"""
    name: str | None = None
    """file name without extension (default: closed_loop, composed for a schedule, or the outcome)"""
    outcome: Literal["any", "success", "failure"] = "any"
    """render the first episode from --seed on that ends in this outcome (the env's info['is_success'] at the
    last step, e.g. Fetch and Four Rooms); any: the episodes from --seed as they come"""
    search: int = 200
    """with --outcome: episodes to try (played without frames) before giving up"""

    def __post_init__(self) -> None:
        check_episodes(self.episodes, high=VIDEO_EPISODES_MAX)
        check_at_least(self.max_steps, "--max-steps")
        check_episodes(self.search, "--search")
        check_seed(self.seed, count=max(self.episodes, self.search if self.outcome != "any" else 1))
        if self.name is not None and (self.name in ("", ".", "..") or Path(self.name).name != self.name
                                      or "\\" in self.name):
            raise UserError(f"--name must be a plain file name without folders, got {self.name!r}; the video is "
                            "always written to RUN/videos.")


def video_command(args: VideoArgs) -> tuple[Path, Path]:
    """Write RUN/videos/<name>.mp4 and .gif; returns their paths."""
    from digail.checkpoint import load_model
    from digail.commands.common import check_output_folder, run_env_id
    from digail.eval.composition import CodeSchedule, parse_schedule
    from digail.viz.video import find_outcome, record_video

    run = check_output_folder(args.run)
    videos = run / "videos"
    if videos.exists() and not videos.is_dir():
        raise UserError(f"{videos} is a file, not a folder; move it away to record videos into it.")
    check_writable(videos, "run folder")
    with run_dir_lock(run):  # one writer per run folder
        model, meta = load_model(run / "model.pt")
        env_id = run_env_id(run, meta)
        schedule = CodeSchedule(parse_schedule(args.schedule, model.codes)) if args.schedule else None
        seed = args.seed
        if args.outcome != "any":
            if schedule is not None or args.episodes != 1:
                raise UserError("--outcome picks one closed-loop episode: drop --schedule and --episodes.")
            seed = find_outcome(model, env_id, args.outcome == "success", args.seed, args.search, args.max_steps)
        name = args.name or ("composed" if schedule is not None else "closed_loop" if args.outcome == "any"
                             else args.outcome)
        mp4, gif = record_video(model, env_id, run / "videos" / f"{name}.mp4", seed=seed, episodes=args.episodes,
                                schedule=schedule, label=f"schedule {args.schedule}" if args.schedule else "",
                                max_steps=args.max_steps)
        print(f"wrote {mp4} and {gif}" + (f" (seed {seed}, {args.outcome})" if args.outcome != "any" else ""))
    return mp4, gif

