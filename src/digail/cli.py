"""The `digail` command line: one subcommand per pipeline stage.

Thin by design: each handler parses a config dataclass (tyro), calls the library and prints where the results
went. Bad input raises `UserError`, printed as one sentence with exit status 2.
"""

from __future__ import annotations

import argparse
import os
import sys
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Annotated, Any, Literal

import tyro

from digail.config import TrainConfig, VAEConfig, get_preset
from digail.errors import UserError


# ----------------------------------------------------------------------------------------------- demos
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


def cmd_demos(args: DemosArgs) -> None:
    from digail.data.demos import record_demos

    path = record_demos(args.env, episodes=args.episodes, out=args.out, seed=args.seed,
                        expert=args.expert, force=args.force)
    print(f"wrote demonstrations to {path}")


# -------------------------------------------------------------------------------------------- pretrain
@dataclass(frozen=True)
class PretrainArgs:
    """Pre-train the VAE (macro-policy q, prior p, sub-task policy pi) on demonstrations."""

    demos: str
    """Minari dataset folder or id"""
    codes: int | None = None
    """number of sub-task codes K (default: the preset's)"""
    preset: str | None = None
    """settings preset (default: the one for the dataset's env)"""
    out: Path | None = None
    """run folder (default: runs/<env>__vae__s<seed>__<time>)"""
    seed: int = 0
    """random seed"""
    device: str = "auto"
    """torch device: auto, cpu or cuda"""
    force: bool = False
    """overwrite an existing run folder"""
    vae: VAEConfig = field(default_factory=VAEConfig)
    """VAE settings (start from the preset)"""


def cmd_pretrain(args: PretrainArgs) -> None:
    from digail.algos.vae_pretrain import pretrain_command

    run = pretrain_command(args)
    print(f"VAE run folder: {run}")


# --------------------------------------------------------------------------------------------- segment
@dataclass(frozen=True)
class SegmentArgs:
    """Segment demonstrations with a run's macro-policy and score against oracle labels where present."""

    run: Annotated[Path, tyro.conf.Positional]
    """run folder holding a VAE or trained policy"""
    demos: str | None = None
    """dataset to segment (default: the run's training demonstrations)"""


def cmd_segment(args: SegmentArgs) -> None:
    from digail.eval.segmentation import segment_command

    segment_command(args.run, args.demos)


# -------------------------------------------------------------------------------------------- evaluate
@dataclass(frozen=True)
class EvaluateArgs:
    """Roll out a run's hierarchical policy (closed-loop macro-policy) and write eval.json."""

    run: Annotated[Path, tyro.conf.Positional]
    """run folder"""
    episodes: int = 300
    """evaluation episodes (paper: 300)"""
    seed: int = 10_000
    """seed of the first evaluation episode"""
    stochastic: bool = False
    """sample actions from pi instead of taking its mean / most likely action (the default, as in SB3)"""
    video: bool = False
    """also record a video of the first episodes into RUN/videos"""


def cmd_evaluate(args: EvaluateArgs) -> None:
    from digail.eval.returns import evaluate_command

    evaluate_command(args.run, episodes=args.episodes, seed=args.seed, deterministic=not args.stochastic,
                     video=args.video)


# ----------------------------------------------------------------------------------------------- train
@dataclass(frozen=True)
class TrainArgs:
    """Train with GAIL or Directed-Info GAIL (PPO on pi(a | s, c), discriminator reward, directed-info bonus)."""

    env: str = ""
    """environment id (default: the dataset's env)"""
    demos: str = ""
    """Minari dataset folder or id"""
    method: Literal["digail", "gail"] = "digail"
    """digail or gail"""
    vae: Path | None = None
    """pre-trained VAE run folder (required for digail: its q and its decoder as the initial policy)"""
    preset: str | None = None
    """settings preset (default: the env's)"""
    out: Path | None = None
    """run folder (default: runs/<env>__<method>__s<seed>__<time>)"""
    bc_weight: float | None = None
    """weight of the BC / L2 term (paper's Fetch experiment; default: the preset's)"""
    resume: Path | None = None
    """continue a killed run from its last checkpoint (other flags are ignored)"""
    seed: int = 0
    """random seed"""
    device: str = "auto"
    """torch device: auto, cpu or cuda"""
    force: bool = False
    """overwrite an existing run folder"""
    train: TrainConfig = field(default_factory=TrainConfig)
    """trainer settings (start from the preset)"""


def cmd_train(args: TrainArgs) -> None:
    from digail.algos.directed_info_gail import train_command

    run = train_command(args)
    print(f"run folder: {run}")


# --------------------------------------------------------------------------------------------- compose
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


def cmd_compose(args: ComposeArgs) -> None:
    from digail.eval.composition import compose_command

    compose_command(args.run, schedule=args.schedule, episodes=args.episodes, seed=args.seed)


# ------------------------------------------------------------------------------------------------- run
@dataclass(frozen=True)
class RunArgs:
    """The whole pipeline: demonstrations -> VAE -> Directed-Info GAIL -> evaluate -> segment -> report."""

    env: Annotated[str, tyro.conf.Positional] = "digail/CircleWorld-v0"
    """environment id"""
    out: Path | None = None
    """run folder (default: runs/<env>__digail__s<seed>__<time>)"""
    preset: str | None = None
    """settings preset (default: the env's)"""
    seed: int = 0
    """random seed"""
    episodes: int | None = None
    """evaluation episodes (default: the preset's)"""
    device: str = "auto"
    """torch device"""
    force: bool = False
    """overwrite an existing run folder"""


def cmd_run(args: RunArgs) -> None:
    from digail.pipeline import run_pipeline

    run = run_pipeline(args)
    print(f"done: {run}")


# ---------------------------------------------------------------------------------------------- expert
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


def cmd_expert(args: ExpertArgs) -> None:
    from digail.experts.rl import expert_command

    expert_command(args)


def _video() -> tuple[type, Callable[[Any], Any]]:
    from digail.commands.video import VideoArgs, video_command

    return VideoArgs, video_command


def _report() -> tuple[type, Callable[[Any], Any]]:
    from digail.commands.report import ReportArgs, report_command

    return ReportArgs, report_command


COMMANDS: dict[str, tuple[type, Callable[[Any], None]]] = {
    "demos": (DemosArgs, cmd_demos),
    "pretrain": (PretrainArgs, cmd_pretrain),
    "segment": (SegmentArgs, cmd_segment),
    "train": (TrainArgs, cmd_train),
    "evaluate": (EvaluateArgs, cmd_evaluate),
    "compose": (ComposeArgs, cmd_compose),
    "run": (RunArgs, cmd_run),
    "expert": (ExpertArgs, cmd_expert),
    "video": _video(),
    "report": _report(),
}


def _first_line(cls: type) -> str:
    return (cls.__doc__ or "").strip().splitlines()[0]


def _usage() -> str:
    lines = ["usage: digail COMMAND [ARGS] ...", "",
             "Directed-Info GAIL: sub-task discovery and hierarchical imitation.",
             "", "commands:"]
    width = max(map(len, COMMANDS))
    lines += [f"  {name:<{width}}  {_first_line(cls)}" for name, (cls, _) in COMMANDS.items()]
    lines += ["", "`digail COMMAND --help` shows a command's options."]
    return "\n".join(lines)


def _preset_defaults(cls: type, argv: Sequence[str]) -> Any:
    """Defaults for commands whose nested configs start from a preset chosen by --preset / env / dataset."""
    if cls not in (PretrainArgs, TrainArgs):
        return None
    pre = argparse.ArgumentParser(add_help=False)
    pre.add_argument("--preset", default=None)
    pre.add_argument("--env", default="")
    pre.add_argument("--demos", default="")
    known, _ = pre.parse_known_args(list(argv))
    env_id = known.env
    if not env_id and known.demos:
        from digail.data.minari_io import dataset_env_id

        try:
            env_id = dataset_env_id(known.demos)
        except UserError:
            env_id = ""  # reported properly by the command itself
    preset = get_preset(known.preset, env_id)
    if cls is PretrainArgs:
        return PretrainArgs(demos=known.demos, vae=preset.vae)
    return TrainArgs(env=env_id, demos=known.demos, train=preset.train)


def main(argv: Sequence[str] | None = None) -> int:
    """Entry point of the `digail` console script; returns the exit status."""
    argv = list(sys.argv[1:] if argv is None else argv)
    if not argv or argv[0] in ("-h", "--help"):
        print(_usage())
        return 0 if argv else 2
    name, rest = argv[0], argv[1:]
    if name not in COMMANDS:
        print(f"digail: unknown command {name!r}; run `digail --help` for the list.", file=sys.stderr)
        return 2
    cls, handler = COMMANDS[name]
    os.environ.setdefault("MUJOCO_GL", "egl")
    from digail.utils import set_torch_threads

    set_torch_threads(1)  # small nets: a second thread buys nothing and costs much under load
    try:
        default = _preset_defaults(cls, rest)
        args = tyro.cli(cls, args=rest, prog=f"digail {name}", default=default,
                        description=cls.__doc__)
        handler(args)
    except UserError as exc:
        print(f"digail {name}: error: {exc}", file=sys.stderr)
        return 2
    except SystemExit as exc:  # tyro / argparse: bad flags exit 2 already, --help exits 0
        return int(exc.code or 0)
    except KeyboardInterrupt:
        print(f"digail {name}: interrupted; a training run can be continued with --resume.", file=sys.stderr)
        return 130
    return 0


if __name__ == "__main__":
    sys.exit(main())
