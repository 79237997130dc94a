"""`digail sweep`: envs x methods x seeds (x override values) on Ray, each trial as the CLI runs it, then the tables.

The work is in `digail.sweep` (grids and spec files, the plan with shared VAEs, the Ray engine, the summary, the
Optuna search); this module is its flags.
"""

from __future__ import annotations

import os
import sys
from dataclasses import dataclass
from pathlib import Path
from typing import Annotated, Any, Literal

from tyro.conf import arg

from digail.errors import UserError


def _flag(metavar: str, hint: str = "") -> object:
    """A flag whose help names its default itself (or says it is optional) instead of tyro's "(default: None)"."""
    return arg(metavar=metavar, help_behavior_hint=hint)


@dataclass(frozen=True)
class SweepArgs:
    """Run envs x methods x seeds (x override values) on Ray, every trial as the CLI runs it, and tabulate."""

    envs: Annotated[tuple[str, ...] | None, _flag("ENV [ENV ...]", "(optional)")] = None
    """environment ids (with --spec: keep only these of its trials)"""
    methods: Annotated[tuple[str, ...] | None, _flag("METHOD [METHOD ...]")] = None
    """vae, gail, digail, gail-l2, digail-l2 (default: digail)"""
    seeds: Annotated[tuple[int, ...] | None, _flag("INT [INT ...]")] = None
    """seeds (default: 0); the trials of one (env, seed) share its VAE"""
    preset: Annotated[str | None, _flag("NAME")] = None
    """settings preset of every stage (default: each env's)"""
    episodes: Annotated[int | None, _flag("INT")] = None
    """evaluation episodes (default: the preset's, 300)"""
    set: Annotated[tuple[str, ...], _flag("KEY=V [KEY=V ...]", "(optional)")] = ()
    """overrides KEY=V, KEY=V1,V2 (a grid) or KEY=LOW..HIGH[:log] (searched), e.g. train.bonus_weight=0.01,0.1"""
    spec: Annotated[Path | None, _flag("SPEC.toml", "(optional)")] = None
    """TOML sweep spec (benchmarks/sweeps/*.toml); the flags narrow it or add overrides"""
    out: Annotated[Path | None, _flag("SWEEP", "(optional)")] = None
    """sweep folder: one run folder per trial, trials/, logs/, results.json, results.md"""
    summarize: Annotated[Path | None, _flag("SWEEP", "(optional)")] = None
    """only (re)write the tables of this sweep folder"""
    address: Annotated[str | None, _flag("ADDRESS")] = None
    """Ray cluster address (default: $RAY_ADDRESS, else a local Ray sized to this machine)"""
    num_cpus: Annotated[int | None, _flag("INT")] = None
    """CPUs of the local Ray, at least 1 (default: all cores)"""
    retries: Annotated[int | None, _flag("INT")] = None
    """extra attempts of a failed trial (default: the spec's, 1)"""
    cpus_per_trial: Annotated[float | None, _flag("FLOAT")] = None
    """CPUs each trial declares to Ray (default: 1)"""
    gpus_per_trial: Annotated[float | None, _flag("FLOAT")] = None
    """GPUs each trial declares to Ray (default: 0); above 0 the trial's VAE and trainer run on cuda"""
    shared_fs: bool = False
    """the sweep folder is at the same path on every node of the cluster, so trials work in it directly; without
    it a trial on another node gets and returns its folders through Ray"""
    dashboard: bool = False
    """start Ray's dashboard (on 127.0.0.1) with the local Ray"""
    search: Literal["optuna"] | None = None
    """search the range overrides with Optuna through Ray Tune instead of running a grid"""
    trials: Annotated[int | None, _flag("INT")] = None
    """settings the search samples (default: 8)"""
    metric: Annotated[str | None, _flag("METRIC")] = None
    """the search's objective, median over seeds: eval/<eval.json key> or seg/<segmentation.json key>
    (default: eval/normalized_return)"""
    mode: Literal["max", "min"] | None = None
    """maximise or minimise the metric (default: max)"""

    def __post_init__(self) -> None:
        from digail.checks import check_at_least

        # 0 would read as "unset" further on and quietly mean every core
        check_at_least(self.num_cpus, "--num-cpus")


def sweep_command(args: SweepArgs) -> dict[str, Any]:
    """Run the sweep (or only summarise one); print its tables; returns results.json's content.

    Every input is checked before Ray starts or anything is written. Exits with status 1, after the tables, when
    trials failed."""
    from digail.sweep import check_out, run_sweep, summarize_sweep
    from digail.sweep.plan import plan
    from digail.sweep.spec import build_spec

    if args.summarize is not None:
        result = summarize_sweep(args.summarize)
    else:
        if args.out is None:
            raise UserError("no sweep folder given; pass --out SWEEP (or --summarize SWEEP for the tables).")
        check_out(Path(args.out))
        spec = build_spec(envs=args.envs, methods=args.methods, seeds=args.seeds, preset=args.preset,
                          episodes=args.episodes, sets=args.set, spec_file=args.spec, retries=args.retries,
                          cpus_per_trial=args.cpus_per_trial, gpus_per_trial=args.gpus_per_trial,
                          search=args.search, trials=args.trials, metric=args.metric, mode=args.mode)
        check_spec(spec, plan(spec) if spec.search is None else [])
        if spec.search is not None and (args.address or os.environ.get("RAY_ADDRESS")) and not args.shared_fs:
            raise UserError("a search on a Ray cluster runs its trials in the sweep folder itself; put --out on a "
                            "filesystem every node sees and pass --shared-fs.")
        result = run_sweep(spec, args.out, address=args.address, num_cpus=args.num_cpus, dashboard=args.dashboard,
                           shared_fs=args.shared_fs)
    tables = Path(result["sweep"]) / "results.md"
    print(tables.read_text())
    print(f"tables: {tables} and {tables.with_name('results.json')}")
    failed = result.get("failed") or []
    if failed and args.summarize is None:
        trials = sum(1 for f in failed if "/pretrain_s" not in f["job"])
        vaes = len(failed) - trials
        what = f"{trials} of {result['trials']} trials" + (f" and {vaes} VAE pre-training(s)" if vaes else "")
        print(f"digail sweep: {what} failed (errors in results.md and {Path(result['sweep']) / 'logs'}); run the "
              "same command again to retry them.", file=sys.stderr)
        raise SystemExit(1)
    return result


STAGE_OF_PREFIX = {"vae": "pretrain", "pretrain": "pretrain", "train": "train", "evaluate": "evaluate",
                   "segment": "segment"}
"""override prefix -> the `digail` command that takes it"""


def check_spec(spec: Any, jobs: list[Any]) -> None:
    """Check what a sweep's trials would do, as their commands would, before anything starts: every env id and its
    demonstrations, every override (key and value, whichever methods read it) and every stage's command line."""
    from digail.sweep.plan import flag_args
    from digail.sweep.spec import Range

    for grid in spec.grids:
        for env in grid.envs:
            demos = grid.demos or _default_demos(env)
            _check_env(env, demos, from_grid=grid.demos is not None)
        demos = grid.demos or _default_demos(grid.envs[0])
        for key, values in grid.overrides:
            head = key.partition(".")[0]
            # the demonstration subset is read by the VAE's pre-training and the training alike
            stages = ("pretrain", "train") if head == "demos" else (STAGE_OF_PREFIX[head],)
            for value, stage in ((v, s) for v in values for s in stages):
                tries = [value] if not isinstance(value, Range) else [
                    int(v) if value.integer else v for v in (value.low, value.high)]
                for v in tries:
                    base = {"pretrain": ["--demos", demos], "train": ["--method", "digail", "--demos", demos],
                            "evaluate": ["RUN"], "segment": ["RUN"]}[stage]
                    preset = ["--preset", grid.preset] if grid.preset and stage in ("pretrain", "train") else []
                    _dry_parse(stage, [*base, *preset, *flag_args(key, v)],
                               f"--set {key}={v}", f"`digail {stage}` takes no such value")
            if key == "train.imitation.disc_obs":
                for v in values:
                    _check_view(v, f"--set {key}")
    seen: set[tuple[str, ...]] = set()
    for job in jobs:
        for stage in job.stages:
            if stage.name in STAGE_OF_PREFIX.values() and stage.argv not in seen:
                seen.add(stage.argv)
                _dry_parse(stage.name, list(stage.argv[1:]), f"trial {job.id}", "its command would fail")
                argv = list(stage.argv)
                for i, tok in enumerate(argv[:-1]):
                    if tok == "--train.imitation.disc-obs":
                        _check_view(argv[i + 1], f"trial {job.id}: --train.imitation.disc-obs")


def _check_view(value: Any, flag: str) -> None:
    """A D view of the user's (`module:function`) resolves here, before Ray starts, to a function of one argument
    in a module of the user's (not the standard library): a trial would otherwise be the first to run it."""
    if isinstance(value, str) and ":" in value:
        from digail.user_envs import import_function

        import_function(value, flag)


def _default_demos(env: str) -> str:
    from digail.data.demos import default_dataset_id

    return default_dataset_id(env)


def _check_env(env: str, demos: str, *, from_grid: bool) -> None:
    """An env id digail or Gymnasium knows, whose demonstrations exist and (when they record one) were recorded in
    it."""
    from digail.data.minari_io import dataset_env_id, resolve_dataset
    from digail.envs.registry import check_env_id
    from digail.user_envs import import_env_module

    env_id = import_env_module(env)  # `module:EnvId` on the sweep's command line or in its spec: the user's to name
    check_env_id(env_id)
    how = "fix the spec's demos" if from_grid else f"record them with `digail demos {env}` or set demos"
    try:
        resolve_dataset(demos)
    except UserError as exc:
        raise UserError(f"env {env}: its demonstrations {demos!r} cannot be read ({_first(exc)}); {how}.") from None
    try:
        recorded = dataset_env_id(demos)
    except UserError:
        return  # data that records no env: the stages run it in the env the sweep names
    if recorded != env_id:
        raise UserError(f"env {env}: the demonstrations {demos!r} were recorded in {recorded}; give that env or "
                        "other demos.")


def _first(exc: BaseException) -> str:
    return " ".join(str(exc).split()).rstrip(".")


def _dry_parse(stage: str, argv: list[str], what: str, problem: str) -> None:
    """Parse `digail STAGE argv` as the CLI would (its preset defaults included), running nothing."""
    import importlib

    import tyro
    from tyro import _errors as tyro_errors

    module = importlib.import_module(f"digail.commands.{stage}")
    cls = {"pretrain": "PretrainArgs", "train": "TrainArgs", "evaluate": "EvaluateArgs", "segment": "SegmentArgs"}
    defaults = getattr(module, "defaults", None)

    def refuse(event: Any) -> None:
        tokens = getattr(event, "tokens", None)
        if tokens:
            flags = [t for t in tokens if str(t).startswith("-")] or tokens
            raise UserError(f"{what}: `digail {stage}` has no option {' '.join(flags)}; see `digail {stage} "
                            "--help` for the options.")
        message = " ".join(str(getattr(event, "message", "") or type(event).__name__).split())
        raise UserError(f"{what}: {problem} ({message.rstrip('.')}); see `digail {stage} --help`.")

    try:
        with tyro_errors.on_parse_error(refuse):
            default = defaults(argv) if defaults is not None else None
            tyro.cli(getattr(module, cls[stage]), args=argv, prog=f"digail {stage}", default=default)
    except UserError as exc:
        if str(exc).startswith(what):
            raise
        raise UserError(f"{what}: {_first(exc)}.") from None
    except SystemExit:
        raise UserError(f"{what}: {problem}; see `digail {stage} --help`.") from None
