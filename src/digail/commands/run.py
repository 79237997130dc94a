"""`digail run [ENV]`: the whole pipeline in one run folder.

demonstrations (shipped, or recorded with the env's expert) -> VAE pre-training -> Directed-Info GAIL ->
closed-loop evaluation -> segmentation -> composition (Circle-World: reversed circles) -> figures -> report.html.
"""

from __future__ import annotations

import contextlib
import json
import subprocess
import sys
import time
from collections.abc import Callable, Iterator
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Annotated, Any

import tyro

from digail.checks import check_episodes
from digail.config import FINAL_EVAL_SEED, check_at_least, check_seed
from digail.errors import UserError
from digail.fsio import check_writable, fresh_dir, remove_path, run_dir_lock, write_json
from digail.utils import resolve_device, set_torch_threads


@dataclass(frozen=True)
class RunArgs:
    """The whole pipeline: demonstrations -> VAE -> Directed-Info GAIL -> evaluate -> segment -> report."""

    env: Annotated[str, tyro.conf.Positional] = "digail/CircleWorld-v0"
    """environment id"""
    demos: str | None = None
    """your own demonstrations: an .npz or HDF5 file in a layout `digail import` reads (imported into RUN/demos) or a
    Minari dataset folder or id (default: the env's shipped dataset, else recorded with its expert)"""
    out: Path | None = None
    """run folder (default: runs/<env>__digail__s<seed>__<time>)"""
    preset: str | None = None
    """settings preset (default: the env's)"""
    seed: int = 0
    """random seed"""
    episodes: int | None = None
    """evaluation episodes (default: the preset's)"""
    demos_episodes: int | None = None
    """use only the first N demonstrations (None: all)"""
    demos_subsample: int = 1
    """keep every K-th transition of each demonstration, from a random offset per episode drawn from the seed
    (GAIL's and DAC's few-demonstration setting: 20); 1 keeps all"""
    device: str = "auto"
    """torch device"""
    force: bool = False
    """overwrite an existing run folder"""
    resume: Path | None = None
    """continue an interrupted run folder at the stage it stopped: finished stages are kept, the training goes on
    from its checkpoint (other flags are ignored)"""
    smoothing_pair: bool = True
    """when the preset's VAE has a smoothing term (no shipped preset has one now), also pre-train a VAE without it
    (the same settings and seed, no polish) into RUN/vae_unsmoothed, for the figure of the two segmentations side
    by side; it runs in a second process beside the training, which uses one thread (--no-smoothing-pair skips
    it)"""

    def __post_init__(self) -> None:
        check_episodes(self.episodes)
        check_at_least(self.demos_episodes, "--demos-episodes")
        check_at_least(self.demos_subsample, "--demos-subsample")
        check_seed(self.seed)


VIDEO_MAX_STEPS = 300
"""Steps of the one video `digail run` records (MuJoCo renders in software here, about 0.5 s a frame)."""


def run_command_line(args: RunArgs, run_dir: Path) -> str:
    """The `digail run` command line that remakes this run (recorded in config.json for the report)."""
    import shlex

    from digail.checkpoint import path_ref

    parts = ["digail", "run", args.env, "--out", str(run_dir), "--seed", str(args.seed)]
    if args.demos is not None:
        parts += ["--demos", str(path_ref(args.demos))]
    if args.preset is not None:
        parts += ["--preset", args.preset]
    if args.episodes is not None:
        parts += ["--episodes", str(args.episodes)]
    if args.device != "auto":
        parts += ["--device", args.device]
    if not args.smoothing_pair:
        parts.append("--no-smoothing-pair")
    return shlex.join(parts)


def _check_demonstrations(env_id: str, demos: str | None) -> Any:
    """Everything that can be wrong with the run's demonstrations, checked before the run folder is made: returns
    the file's demonstrations fitted to the env (`prepare_import`), the Minari dataset checked against it, or None
    (the shipped or recorded ones; refused for an env digail has no expert for)."""
    from digail.data.demos import default_dataset_id
    from digail.data.importers import is_import_source, prepare_import
    from digail.data.minari_io import load_dataset, shipped_dataset_ids
    from digail.data.validation import check_matches_env
    from digail.envs.registry import env_spec

    if demos is None:
        if default_dataset_id(env_id) not in shipped_dataset_ids() and env_spec(env_id) is None:
            raise UserError(f"digail has no demonstrations or expert for {env_id}; pass your own with --demos (an SB3, "
                            "imitation, D4RL or plain-array .npz / HDF5 file, or a Minari dataset).")
        return None
    if is_import_source(demos):
        return prepare_import(demos, env_id=env_id)
    dataset = load_dataset(demos)
    check_matches_env(dataset, env_id)
    return dataset


def _demonstrations(env_id: str, run_dir: Path, seed: int, demos: str | None = None,
                    checked: Any = None) -> tuple[Any, str]:
    """The run's dataset and how config.json refers to it: `demos` (a file imported into RUN/demos, or a Minari
    dataset), else the shipped dataset for `env_id` when there is one, else demonstrations recorded into RUN/demos.
    `checked` is `_check_demonstrations`'s result, when it ran."""
    from digail.data.demos import default_dataset_id, record_demos
    from digail.data.importers import Imported, is_import_source, prepare_import, write_imported
    from digail.data.minari_io import Dataset, load_dataset, shipped_dataset_ids

    if demos is not None and is_import_source(demos):
        path = run_dir / "demos"
        if not path.is_dir():  # written atomically: a folder that exists is complete (kept when resuming)
            imported = checked if isinstance(checked, Imported) else prepare_import(demos, env_id=env_id)
            write_imported(imported, path)
        return load_dataset(str(path)), str(path)
    if demos is not None:
        return (checked if isinstance(checked, Dataset) else load_dataset(demos)), demos
    dataset_id = default_dataset_id(env_id)
    if dataset_id in shipped_dataset_ids():
        return load_dataset(dataset_id), dataset_id
    path = run_dir / "demos"
    if not path.is_dir():  # recorded atomically: a folder that exists is complete (kept when resuming)
        path = record_demos(env_id, out=path, seed=seed)
    return load_dataset(str(path)), str(path)


def run_command(args: RunArgs) -> Path:
    """Run every stage into one folder; returns it."""
    from digail.commands.common import inputs, new_run_dir
    from digail.envs import make_env
    from digail.envs.registry import preset_for

    set_torch_threads(1)
    resuming = False
    if args.resume is not None:
        resuming, args = True, _resume_args(Path(args.resume))
    device = resolve_device(args.device)
    make_env(args.env).close()  # an unknown id fails here, before anything is written
    preset = preset_for(args.env, args.preset)
    checked = None if resuming else _check_demonstrations(args.env, args.demos)
    if not resuming:
        _check_subset(args, checked)
    if resuming:
        run_dir = Path(args.out or ".")
        check_writable(run_dir, "run folder")
        held = run_dir_lock(run_dir)
        print(f"resuming {run_dir}")
    else:
        run_dir = new_run_dir(args.out, args.env, "digail", args.seed, args.force, resume_command="run",
                              reads=inputs(args.demos))
        held = fresh_dir(run_dir, args.force)  # --force: the old folder's files go first
    try:
        with held:  # the folder is this command's until the end: a second writer is refused, --force included
            return _run_stages(args, run_dir, resuming, preset, device, checked)
    except _SubsetRefused:
        # refused before any stage ran (demonstrations recorded into the folder, then found too few): the folder
        # holds only what this command wrote, and left in place it would block the corrected command
        if not resuming:
            remove_path(run_dir)
        raise


class _SubsetRefused(UserError):
    """`--demos-episodes` / `--demos-subsample` do not fit the demonstrations the run recorded itself."""


def _check_subset(args: RunArgs, checked: Any) -> None:
    """Refuse a `--demos-episodes` / `--demos-subsample` that the demonstrations cannot give, before the run folder
    is made: the user's (`checked`) or the shipped dataset (recorded ones are checked once recorded)."""
    from digail.data.demos import default_dataset_id
    from digail.data.minari_io import load_dataset, shipped_dataset_ids
    from digail.data.subset import select_demos

    if args.demos_episodes is None and args.demos_subsample == 1:
        return
    trajs = getattr(checked, "trajs", None)
    if trajs is None and args.demos is None and default_dataset_id(args.env) in shipped_dataset_ids():
        trajs = load_dataset(default_dataset_id(args.env)).trajs
    if trajs is not None:
        select_demos(list(trajs), args.demos_episodes, args.demos_subsample, args.seed)


def _run_stages(args: RunArgs, run_dir: Path, resuming: bool, preset: Any, device: Any, checked: Any) -> Path:
    """Every stage of `run_command` in its (held) run folder; finished stages of an interrupted run are kept."""
    from digail.algos.directed_info_gail import build_trainer
    from digail.algos.vae_pretrain import auto_epochs, pretrain
    from digail.checkpoint import load_model, path_ref, run_config, save_model, write_run_config
    from digail.commands.report import make_figures
    from digail.commands.train import TrainArgs
    from digail.config import to_dict
    from digail.data.validation import check_matches_env
    from digail.envs.registry import env_spec, init_pieces_fn
    from digail.eval.composition import compose, episode_limit, parse_schedule, schedule_in_codes
    from digail.eval.returns import evaluate
    from digail.eval.segmentation import write_segmentation
    from digail.nets.policy import ActionSpec
    from digail.viz.report import BEFORE_POLISH, write_report
    from digail.viz.video import record_video

    cfg = replace(preset.train, method="digail")
    vae_dir = run_dir / "vae"
    run_args = replace(args, out=run_dir.resolve(), resume=None, force=False, demos=path_ref(args.demos))
    # written first, so that an interrupted run can be resumed from any stage
    write_run_config(run_dir, run_config(kind="digail", env_id=args.env, demos=None, seed=args.seed,
                                         preset=args.preset, device=args.device, vae=preset.vae, train=cfg,
                                         vae_run=None, pipeline=True, run_args=to_dict(run_args)))
    timings: dict[str, float] = {}

    t0 = time.perf_counter()
    dataset, demos_ref = _demonstrations(args.env, run_dir, args.seed, args.demos, checked)
    check_matches_env(dataset, args.env)
    from digail.data.subset import select_demos

    try:
        trajs = select_demos(list(dataset.trajs), args.demos_episodes, args.demos_subsample, args.seed)
    except UserError as exc:
        raise _SubsetRefused(str(exc)) from None
    timings["demos_s"] = time.perf_counter() - t0
    print(f"[1/5] {len(trajs)} demonstrations of {args.env} ({demos_ref})")

    t0 = time.perf_counter()
    if (vae_dir / "model.pt").is_file() and (vae_dir / "config.json").is_file():
        vae_model, _ = load_model(vae_dir / "model.pt", device)
        print("[2/5] VAE pre-trained (kept from the interrupted run)")
    else:
        remove_path(vae_dir)  # a VAE stage cut short starts again from scratch
        vae_dir.mkdir()
        action = ActionSpec.from_space(dataset.action_space) if dataset.action_space is not None else None
        vae_model, _ = pretrain(trajs, preset.vae, action_spec=action, seed=args.seed, device=str(device),
                                log_dir=vae_dir, pieces=init_pieces_fn(args.env),
                                before_polish=_segment_into(run_dir / BEFORE_POLISH, trajs, demos_ref))
        vae_cfg = run_config(kind="vae", env_id=args.env, demos=demos_ref, seed=args.seed, preset=args.preset,
                             device=args.device, vae=preset.vae, pipeline=True)
        vae_cfg["vae"]["epochs_run"] = auto_epochs(preset.vae, len(trajs))  # as `digail pretrain` records it
        write_run_config(vae_dir, vae_cfg)
        save_model(vae_dir / "model.pt", vae_model, kind="vae", config=vae_cfg, env_id=args.env)  # the mark
        timings["pretrain_s"] = time.perf_counter() - t0
        print(f"[2/5] VAE pre-trained in {timings['pretrain_s']:.0f}s")

    pair = args.smoothing_pair and preset.vae.smoothing_weight > 0
    with _unsmoothed_vae_beside(run_dir, args, demos_ref, timings) if pair else contextlib.nullcontext():
        t0 = time.perf_counter()
        # the run folder is a `digail train` run too (its `args` let `digail train --resume RUN` continue it)
        train_args = TrainArgs(env=args.env, demos=str(path_ref(demos_ref)), method="digail", vae=vae_dir.resolve(),
                               preset=args.preset, out=run_dir, seed=args.seed, device=args.device, train=cfg,
                               demos_episodes=args.demos_episodes, demos_subsample=args.demos_subsample)
        config = run_config(kind="digail", env_id=args.env, demos=demos_ref, seed=args.seed, preset=args.preset,
                            device=args.device, vae=preset.vae, train=cfg, vae_run=vae_dir, args=train_args,
                            pipeline=True, run_args=to_dict(run_args), command=run_command_line(args, run_dir))
        write_run_config(run_dir, config)
        trainer = build_trainer(args.env, trajs, cfg, vae_model=vae_model, seed=args.seed, run_dir=run_dir,
                                device=device)
        config["fast_path"] = trainer.fast_path  # what the trainer read when it was built
        write_run_config(run_dir, config)
        trainer.model_config = config
        ckpt = run_dir / "checkpoint.pt"
        try:
            if resuming and ckpt.is_file():
                trainer.load_checkpoint(ckpt)
                if trainer.iteration < cfg.iterations:
                    print(f"      training resumes at iteration {trainer.iteration}/{cfg.iterations}")
            if trainer.iteration < cfg.iterations or not (run_dir / "model.pt").is_file():
                trainer.train()
                trainer.save_checkpoint(ckpt)
                timings["train_s"] = time.perf_counter() - t0
                print(f"[3/5] Directed-Info GAIL trained in {timings['train_s']:.0f}s")
            else:
                print("[3/5] Directed-Info GAIL trained (kept from the interrupted run)")
        finally:
            trainer.close()
        model = trainer.model

        t0 = time.perf_counter()
        episodes = args.episodes if args.episodes is not None else preset.eval_episodes
        result = evaluate(model, args.env, episodes)
        result["kind"] = "digail"
        write_json(run_dir / "eval.json", result)
        timings["evaluate_s"] = time.perf_counter() - t0
        print(f"[4/5] evaluated on {episodes} episodes: mean return {result['mean_return']:.2f}")

        t0 = time.perf_counter()
        seg = write_segmentation(run_dir, model, trajs, demos=demos_ref)
        composed = None
        schedule = None
        spec = env_spec(args.env)
        if spec is not None and spec.compose_schedule is not None and seg and "mapping" in seg:
            schedule = schedule_in_codes(spec.compose_schedule, seg["mapping"])
            if schedule is None:
                print("      composition skipped: the segmentation did not give every sub-task a code of its own")
        if schedule is not None:
            pairs = parse_schedule(schedule, model.codes, episode_limit(args.env))
            composed, _ = compose(model, args.env, pairs, min(episodes, 100), 20_000)
            composed["schedule"] = schedule
            write_json(run_dir / "compose.json", composed)
        timings["segment_compose_s"] = time.perf_counter() - t0
    t0 = time.perf_counter()
    make_figures(run_dir, model=model, trajs=trajs)
    try:
        record_video(model, args.env, run_dir / "videos" / "closed_loop.mp4", seed=FINAL_EVAL_SEED,
                     max_steps=VIDEO_MAX_STEPS)
    except UserError as exc:  # a missing renderer costs the video, not the run
        print(f"      video skipped: {exc}")
    timings["figures_video_s"] = time.perf_counter() - t0
    write_json(run_dir / "timings.json", timings)
    report = write_report(run_dir)
    print(f"[5/5] segmentation, figures and video written; report: {report}")
    _print_headline(result, seg, composed)
    print(f"done: {run_dir}")
    return run_dir


def _segment_into(folder: Path, trajs: list[Any], demos_ref: str) -> Callable[[Any], None]:
    """A `pretrain(before_polish=...)` hook writing the VAE's own segmentation (before the polish refits q to it)
    into `folder`: codes.npz, segmentation.json, figures/segmentation.png."""
    from digail.eval.segmentation import write_segmentation

    def hook(model: Any) -> None:
        folder.mkdir(parents=True, exist_ok=True)
        write_segmentation(folder, model, trajs, demos=demos_ref)

    return hook


@contextlib.contextmanager
def _unsmoothed_vae_beside(run_dir: Path, args: RunArgs, demos_ref: str, timings: dict[str, float]) -> Iterator[None]:
    """Pre-train the run's VAE without the smoothing term into RUN/vae_unsmoothed, in a second process (`digail
    pretrain`) while the block runs, for the side-by-side figure.

    The same preset and seed with `--vae.smoothing-weight 0 --vae.polish-steps 0`: the figure compares the two
    VAEs' segmentations before any polish (the run's own is kept in `BEFORE_POLISH`), so the polish is not paid
    for. A second process because Directed-Info GAIL trains on one thread: on two idle cores the comparison then
    costs almost no wall-clock time, where in turn it would cost the VAE epochs again. Records
    `pretrain_unsmoothed_s` (its own time) and `wait_unsmoothed_s` (how long the run waited for it at the end);
    a failure costs the figure, not the run.
    """
    from digail.envs.registry import env_spec
    from digail.utils import die_with_parent
    from digail.viz.report import UNSMOOTHED

    out = run_dir / UNSMOOTHED
    spec = env_spec(args.env)
    preset = args.preset or (spec.preset if spec is not None else None)
    if (out / "model.pt").is_file() or preset is None:
        if preset is not None:
            print("      VAE without the smoothing term kept from the interrupted run")
        yield
        return
    demos = str(Path(demos_ref).resolve()) if Path(demos_ref).exists() else demos_ref
    argv = [sys.executable, "-m", "digail.cli", "pretrain", "--demos", demos, "--preset", preset, "--seed",
            str(args.seed), "--device", args.device, "--out", str(out), "--force", "--vae.smoothing-weight", "0",
            "--vae.polish-steps", "0"]
    log = run_dir / f"{UNSMOOTHED}.log"
    with open(log, "wb") as f:
        proc = subprocess.Popen(argv, stdout=f, stderr=subprocess.STDOUT, preexec_fn=die_with_parent)
    print(f"      pre-training the VAE without the smoothing term beside it (log: {log})")
    try:
        yield
    except BaseException:
        proc.terminate()  # the CLI turns SIGTERM into a clean exit: no temporary folder is left
        proc.wait()
        raise
    t0 = time.perf_counter()
    rc = proc.wait()
    timings["wait_unsmoothed_s"] = time.perf_counter() - t0
    if rc == 0 and (out / "model.pt").is_file():
        with contextlib.suppress(OSError, ValueError, KeyError):
            timings["pretrain_unsmoothed_s"] = float(json.loads((out / "config.json").read_text())["train_time_s"])
        log.unlink(missing_ok=True)
        print(f"      VAE without the smoothing term done (waited {timings['wait_unsmoothed_s']:.0f}s for it)")
    else:
        print(f"      VAE without the smoothing term failed (exit status {rc}, see {log}); the segmentation figure "
              "shows the Viterbi smoother instead")


def _resume_args(run_dir: Path) -> RunArgs:
    """The arguments an interrupted `digail run` folder was started with; one sentence when it is not one."""
    from digail.checkpoint import read_config
    from digail.commands.common import saved_args
    from digail.errors import UserError

    if not run_dir.is_dir():
        raise UserError(f"{run_dir} does not exist; pass the folder of an interrupted `digail run`.")
    config = read_config(run_dir)
    saved = config.get("run_args")
    if not config.get("pipeline") or not isinstance(saved, dict):
        other = " (continue a `digail train` folder with `digail train --resume`)" if config.get("args") else ""
        raise UserError(f"{run_dir} is not a folder made by `digail run`{other}; pass the folder of an interrupted "
                        "`digail run`.")
    args = saved_args(RunArgs, saved, run_dir, "run")
    return replace(args, out=run_dir, resume=run_dir, force=False)


def _print_headline(result: dict[str, Any], seg: dict[str, Any] | None, composed: dict[str, Any] | None) -> None:
    keys = ["mean_return", "success_rate", "path_length_ratio", "order_correct_rate", "radius_error"]
    parts = [f"{k}={result[k]:.3f}" for k in keys if isinstance(result.get(k), float)]
    if seg and "accuracy" in seg:
        parts.append(f"segmentation accuracy={seg['accuracy']:.3f}")
    if composed and "order_reversed_rate" in composed:
        parts.append(f"composed order_reversed_rate={composed['order_reversed_rate']:.3f}")
    print("results: " + ", ".join(parts))
