"""`digail sweep`: envs x methods x seeds (x override values) on Ray, each trial as the CLI runs it, then the tables.

The work is in `digail.sweep` (grids and spec files, the plan with shared VAEs, the Ray engine, the summary, the
Optuna search); this module is its flags.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any, Literal

from digail.errors import UserError


@dataclass(frozen=True)
class SweepArgs:
    """Run envs x methods x seeds (x override values) on Ray, every trial as the CLI runs it, and tabulate."""

    envs: tuple[str, ...] = ()
    """environment ids (with --spec: keep only these of its trials)"""
    methods: tuple[str, ...] = ()
    """vae, gail, digail, gail-l2, digail-l2 (default: digail)"""
    seeds: tuple[int, ...] = ()
    """seeds (default: 0); the trials of one (env, seed) share its VAE"""
    preset: str | None = None
    """settings preset of every stage (default: each env's)"""
    episodes: int | None = None
    """evaluation episodes (default: the preset's, 300)"""
    set: tuple[str, ...] = ()
    """overrides KEY=V, KEY=V1,V2 (a grid) or KEY=LOW..HIGH[:log] (searched), e.g. train.bonus_weight=0.01,0.1"""
    spec: Path | None = None
    """TOML sweep spec (benchmarks/sweeps/*.toml); the flags narrow it or add overrides"""
    out: Path | None = None
    """sweep folder: one run folder per trial, trials/, logs/, results.json, results.md"""
    summarize: Path | None = None
    """only (re)write the tables of this sweep folder"""
    address: str | None = None
    """Ray cluster address (default: $RAY_ADDRESS, else a local Ray sized to this machine)"""
    num_cpus: int | None = None
    """CPUs of the local Ray (default: all cores)"""
    retries: int | None = None
    """extra attempts of a failed trial (default: the spec's, 1)"""
    cpus_per_trial: float | None = None
    """CPUs each trial declares to Ray (default: 1)"""
    gpus_per_trial: float | None = None
    """GPUs each trial declares to Ray (default: 0)"""
    dashboard: bool = False
    """start Ray's dashboard with the local Ray"""
    search: Literal["optuna"] | None = None
    """search the range overrides with Optuna through Ray Tune instead of running a grid"""
    trials: int | None = None
    """settings the search samples (default: 8)"""
    metric: str | None = None
    """the search's objective, median over seeds: eval/<eval.json key> or seg/<segmentation.json key>
    (default: eval/normalized_return)"""
    mode: Literal["max", "min"] | None = None
    """maximise or minimise the metric (default: max)"""


def sweep_command(args: SweepArgs) -> dict[str, Any]:
    """Run the sweep (or only summarise one); print its tables; returns results.json's content."""
    from digail.sweep import run_sweep, summarize_sweep
    from digail.sweep.spec import build_spec

    if args.summarize is not None:
        result = summarize_sweep(args.summarize)
    else:
        if args.out is None:
            raise UserError("no sweep folder given; pass --out SWEEP (or --summarize SWEEP for the tables).")
        spec = build_spec(envs=args.envs, methods=args.methods, seeds=args.seeds, preset=args.preset,
                          episodes=args.episodes, sets=args.set, spec_file=args.spec, retries=args.retries,
                          cpus_per_trial=args.cpus_per_trial, gpus_per_trial=args.gpus_per_trial,
                          search=args.search, trials=args.trials, metric=args.metric, mode=args.mode)
        result = run_sweep(spec, args.out, address=args.address, num_cpus=args.num_cpus, dashboard=args.dashboard)
    tables = Path(result["sweep"]) / "results.md"
    print(tables.read_text())
    print(f"tables: {tables} and {tables.with_name('results.json')}")
    return result
