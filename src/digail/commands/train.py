"""`digail train`: GAIL or Directed-Info GAIL in a run folder (or `--resume` a killed one)."""

from __future__ import annotations

import sys
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any, Literal

import numpy as np

from digail.checks import likely_cause
from digail.config import FINAL_EVAL_SEED, TrainConfig, check_at_least, check_seed
from digail.data.trajectory import Trajectory
from digail.errors import TrainingError, UserError
from digail.nets.vae import HierarchicalPolicy


@dataclass(frozen=True)
class TrainArgs:
    """Train with GAIL or Directed-Info GAIL (PPO on pi(a | s, c), discriminator reward, directed-info bonus)."""

    env: str = ""
    """environment id (default: the dataset's env)"""
    demos: str = ""
    """Minari dataset folder or id"""
    demos_episodes: int | None = None
    """use only the first N demonstrations (None: all)"""
    demos_subsample: int = 1
    """keep every K-th transition of each demonstration, from a random offset per episode drawn from the seed
    (GAIL's and DAC's few-demonstration setting: 20); 1 keeps all"""
    method: Literal["digail", "gail"] = "digail"
    """digail or gail"""
    vae: Path | None = None
    """pre-trained VAE run folder (required for digail: its q and its decoder as the initial policy)"""
    preset: str | None = None
    """settings preset (default: the env's)"""
    out: Path | None = None
    """run folder (default: runs/<env>__<method>__s<seed>__<time>)"""
    resume: Path | None = None
    """continue a killed run from its last checkpoint (other flags are ignored, except `--until`)"""
    until: int | None = None
    """with `--resume`: train until this many iterations in all, extending a run past the length it was started
    with (its eval.json, which describes the shorter run, is kept as eval.iteration-N.json)"""
    seed: int = 0
    """random seed"""
    device: str = "auto"
    """torch device: auto, cpu or cuda"""
    force: bool = False
    """overwrite an existing run folder"""
    train: TrainConfig = field(default_factory=TrainConfig)
    """trainer settings (start from the preset)"""

    def __post_init__(self) -> None:
        check_seed(self.seed)
        check_at_least(self.demos_episodes, "--demos-episodes")
        check_at_least(self.demos_subsample, "--demos-subsample")
        check_at_least(self.until, "--until")
        if self.until is not None and self.resume is None:
            raise UserError("--until extends a training run: pass the run folder with --resume RUN as well.")


def defaults(argv: Sequence[str]) -> TrainArgs:
    """Defaults whose trainer settings start from the preset the command line asks for."""
    from digail.commands.common import preset_from_argv

    preset, env_id, demos = preset_from_argv(argv)
    return TrainArgs(env=env_id, demos=demos, train=preset.train)


def train_command(args: TrainArgs) -> Path:
    """Validate everything, then train (or resume) in a run folder; returns it."""
    from digail.algos.directed_info_gail import build_trainer
    from digail.checkpoint import path_ref, run_config, write_run_config
    from digail.commands.common import inputs, new_run_dir
    from digail.fsio import check_writable, fresh_dir, run_dir_lock
    from digail.utils import resolve_device, set_torch_threads

    set_torch_threads(1)
    run_dir = None
    until = args.until
    if args.resume is not None:
        run_dir = Path(args.resume)
        named_view = args.train.imitation.disc_obs
        args = resume_args(run_dir)
        check_recorded_view(run_dir, args.train.imitation.disc_obs, named_view)
        if until is not None:
            args = replace(args, train=replace(args.train, iterations=until))
    if ":" in args.train.imitation.disc_obs:  # the user's view: imported and checked before the data is read
        from digail.user_envs import import_function

        import_function(args.train.imitation.disc_obs, "--train.imitation.disc-obs")
    device = resolve_device(args.device)
    demos, env_id = load_demos(args.demos, args.env, episodes=args.demos_episodes, every=args.demos_subsample,
                               seed=args.seed)
    cfg = args.train
    cfg = replace(cfg, method=args.method)
    vae_model = None
    if args.vae is not None:
        from digail.checkpoint import load_model

        vae_model, meta = load_model(Path(args.vae) / "model.pt")
        if meta.get("env_id") not in (None, env_id):
            raise UserError(f"the VAE in {args.vae} was trained on {meta.get('env_id')}, not {env_id}; "
                            "pre-train one on this env's demonstrations.")
        if vae_model.obs_dim != int(np.asarray(demos[0].obs).reshape(len(demos[0].obs), -1).shape[1]):
            raise UserError(f"the VAE in {args.vae} expects {vae_model.obs_dim}-d observations but the "
                            "demonstrations have another size; pre-train it on these demonstrations.")
    if run_dir is None:
        run_dir = new_run_dir(args.out, env_id, cfg.method, args.seed, args.force, resume_command="train",
                              reads=inputs(args.demos, (args.vae, "the VAE run")))
    else:
        check_writable(run_dir, "run folder")
    config = run_config(kind=cfg.method, env_id=env_id, demos=args.demos, seed=args.seed, preset=args.preset,
                        device=args.device, train=cfg, vae_run=args.vae,
                        args=replace(args, train=cfg, env=env_id, demos=path_ref(args.demos) or "",
                                     vae=None if args.vae is None else Path(args.vae).resolve()))
    trainer = build_trainer(env_id, demos, cfg, vae_model=vae_model, seed=args.seed, run_dir=None,
                            device=device)
    config["fast_path"] = trainer.fast_path
    ckpt = run_dir / "checkpoint.pt"
    made = False
    try:
        # the folder is this command's while it trains: a second writer is refused, --force included
        with run_dir_lock(run_dir) if args.resume is not None else fresh_dir(run_dir, args.force):
            made = args.resume is None
            if args.resume is None:
                write_run_config(run_dir, config)
            elif ckpt.exists():
                trainer.load_checkpoint(ckpt)
                print(f"resuming {run_dir} at iteration {trainer.iteration}/{cfg.iterations}")
            else:
                print(f"no checkpoint in {run_dir} yet: its training starts again from iteration 0")
            if until is not None:
                extend_run(run_dir, config, trainer.iteration, until)
            trainer.model_config = config
            trainer.run_dir = run_dir
            trainer.train(evaluate=periodic_evaluation(env_id, cfg))
            trainer.save_checkpoint(ckpt)
    except (UserError, TrainingError) as exc:
        # bad input found only once training ran (a view of the user's failing on the agent's observations) or a
        # NaN loss: a folder this command made that holds no checkpoint yet is nothing to resume, so it goes
        message = likely_cause(str(exc), cfg.imitation) if isinstance(exc, TrainingError) else str(exc)
        if made and not ckpt.exists():
            from digail.fsio import remove_path

            remove_path(run_dir)
            message = message.replace("the last good checkpoint is kept", f"no checkpoint was saved yet, so "
                                      f"{run_dir} is removed")
        if isinstance(exc, TrainingError):
            raise TrainingError(message) from None
        raise
    finally:
        trainer.close()
    print(f"run folder: {run_dir}")
    return run_dir


def extend_run(run_dir: Path, config: dict[str, Any], done: int, until: int) -> None:
    """Record a longer budget in RUN/config.json (so a kill during the extension resumes to it) and set the
    shorter run's eval.json aside; an `until` below the iterations done is refused, one equal to them is a no-op."""
    from digail.checkpoint import write_run_config

    if until < done:
        raise UserError(f"--until {until}: {run_dir} has done {done} iterations already and a run cannot be "
                        "shortened; pass a larger number to train it longer.")
    if until == done:  # nothing left to train (e.g. a repeated call after the extension finished)
        return
    write_run_config(run_dir, config)
    old_eval = run_dir / "eval.json"
    if old_eval.exists():
        old_eval.replace(run_dir / f"eval.iteration-{done}.json")


def resume_args(run_dir: Path) -> TrainArgs:
    """The arguments a training run folder was started with (RUN/config.json), with its dataset and VAE paths
    found from any working directory; one sentence when the folder holds no training to continue."""
    from digail.checkpoint import read_config
    from digail.commands.common import resolve_ref, saved_args

    run_dir = Path(run_dir)
    if not run_dir.is_dir():
        raise UserError(f"{run_dir} does not exist; pass the folder of a `digail train` or `digail run` run.")
    config = read_config(run_dir)
    if config.get("kind") == "vae":
        raise UserError(f"{run_dir} is a VAE run folder (from `digail pretrain`) with no training to resume; train "
                        f"on it with `digail train --vae {run_dir} --demos D`.")
    saved = config.get("args")
    if not isinstance(saved, dict):
        what = "no config.json" if not config else "its config.json records no training arguments"
        raise UserError(f"{run_dir} is not a training run folder ({what}); pass a folder made by `digail train` "
                        "or `digail run`.")
    if saved.get("bc_weight") is not None:  # a run started with the old top-level --bc-weight, which overrode this
        saved = {**saved, "train": {**(saved.get("train") or {}), "bc_weight": saved["bc_weight"]}}
    args = saved_args(TrainArgs, saved, run_dir, "training")
    vae = resolve_ref(run_dir, args.vae)
    return replace(args, demos=resolve_ref(run_dir, args.demos) or "", vae=None if vae is None else Path(vae),
                   out=run_dir, resume=run_dir, force=False)


def check_recorded_view(run_dir: Path, recorded: str, named: str) -> None:
    """A run folder's D view of the user's own (`module:function` in config.json) is code the folder names: it is
    imported only when this command line names the same view, else refused before anything is imported. The views
    digail ships (`SHIPPED_VIEWS`) are its own code and pass."""
    from digail.algos.rewards.views import SHIPPED_VIEWS

    if recorded in ("all", "relative") or recorded in SHIPPED_VIEWS or named == recorded:
        return
    raise UserError(f"{run_dir} was trained with D's view {recorded} (its config.json), code that digail runs only "
                    f"when you name it; resume with `digail train --resume {run_dir} "
                    f"--train.imitation.disc-obs {recorded}`.")


def periodic_evaluation(env_id: str, cfg: TrainConfig) -> Callable[[HierarchicalPolicy], dict[str, float]] | None:
    """The `evaluate` hook of `GAIL.train` for `cfg.eval_every` > 0: deterministic closed-loop episodes from the
    final evaluation's seeds, normalised by the expert measured once on the same seeds (None when disabled)."""
    if cfg.eval_every <= 0:
        return None
    from digail.eval.returns import evaluate, expert_summary

    seed = FINAL_EVAL_SEED
    expert = expert_summary(env_id, cfg.eval_episodes, seed)
    denom = expert["mean_return"] if expert is not None else 0.0

    def hook(model: HierarchicalPolicy) -> dict[str, float]:
        result = evaluate(model, env_id, cfg.eval_episodes, seed, deterministic=True, with_expert=False)
        out = {k: float(v) for k, v in result.items()
               if isinstance(v, float) and k not in ("std_return",) and np.isfinite(v)}
        if abs(denom) > 1e-6:
            out["normalized_return"] = out["mean_return"] / denom
        return out

    return hook


def load_demos(demos: str, env: str = "", *, episodes: int | None = None, every: int = 1,
               seed: int = 0) -> tuple[list[Trajectory], str]:
    """The demonstrations of `demos` checked against `env` (default: the dataset's own env), and the env id; with
    `episodes` / `every`, the subset `digail.data.subset.select_demos` keeps."""
    from digail.data.minari_io import load_dataset
    from digail.data.validation import check_matches_env

    if not demos:
        raise UserError("the flag --demos is missing; pass a Minari dataset folder or id.")
    ds = load_dataset(demos)
    env_id = env or ds.env_id
    if not env_id:
        raise UserError(f"the dataset {demos} does not name its environment; pass --env.")
    check_matches_env(ds, env_id)
    if env and ds.env_id and env != ds.env_id:  # same spaces, another env: allowed (a variant), but said
        print(f"note: {demos} was recorded in {ds.env_id}; training in {env}, whose spaces are the same.",
              file=sys.stderr)
    from digail.data.subset import select_demos

    return select_demos(list(ds.trajs), episodes, every, seed), env_id
