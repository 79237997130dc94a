"""Sweeps: envs x methods x seeds (x override values) run on Ray, every trial as the CLI runs it, then the tables.

    from digail.sweep import Grid, SweepSpec, run_sweep
    spec = SweepSpec(grids=(Grid(envs=("digail/CircleWorld-v0",), methods=("vae", "digail"), seeds=(0, 1),
                                 preset="smoke", episodes=10),))
    results = run_sweep(spec, "runs/sweep")          # local Ray; address="ray://head:10001" for a cluster

`spec` parses flags and TOML spec files, `plan` turns a spec into jobs (shared VAEs, `digail` command lines),
`engine` runs them on Ray, `summary` writes results.json / results.md and `search` runs an Optuna search through
Ray Tune. Ray is the optional extra `digail[sweep]`; nothing here imports it before a sweep starts.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

from digail.errors import UserError
from digail.sweep.cluster import start_ray, stop_ray
from digail.sweep.engine import check_consistent, execute, job_done
from digail.sweep.plan import plan
from digail.sweep.record import PLAN_FILE, load_plan, save_plan, summarize_sweep
from digail.sweep.spec import Grid, Range, SearchSpec, SweepSpec, load_spec, parse_set

__all__ = ["PLAN_FILE", "Grid", "Range", "SearchSpec", "SweepSpec", "load_plan", "load_spec", "parse_set", "plan",
           "run_sweep", "save_plan", "start_ray", "stop_ray", "summarize_sweep"]


def _require_ray() -> None:
    try:
        import ray  # noqa: F401
    except ImportError as exc:
        raise UserError("sweeps run on Ray, which is not installed; pip install 'digail[sweep]'.") from exc


def check_out(out: Path) -> None:
    """Refuse, before Ray starts, a sweep folder the output rule (`digail.fsio.check_output`) refuses: a file (or a
    path under one), a link, a FIFO or a device, a folder digail did not make (a sweep writes its marker, plan and
    tables into it), or one that cannot be written. A sweep's own folder is continued."""
    from digail.fsio import check_output, digail_made

    out = Path(out)
    for parent in (out, *out.parents):
        if parent.exists() and not parent.is_dir() and not (parent == out and out.is_symlink()):
            raise UserError(f"{parent} is a file, not a folder; pass a folder (new or a sweep's) to --out.")
    if out.is_dir() and not out.is_symlink() and not digail_made(out):
        raise UserError(f"{out} is a folder digail did not make; a sweep writes only into a new folder or its own "
                        "(to continue it), choose another --out.")
    check_output(out, "folder", force=True, writes="a sweep writes a folder")


def run_sweep(spec: SweepSpec, out: Path | str, *, address: str | None = None, num_cpus: int | None = None,
              dashboard: bool = False, shared_fs: bool = False, summary_every: float = 30.0) -> dict[str, Any]:
    """Run every unfinished trial of `spec` into the sweep folder `out` on Ray, then write and return the tables.

    Everything is checked before Ray starts or a file is written. A search spec (`spec.search`) runs
    `digail.sweep.search.run_search` instead. `shared_fs`: `out` is at the same path on every node of the cluster,
    so trials work in it instead of receiving and returning their folders through Ray."""
    out = Path(out).resolve()
    check_out(out)
    if spec.search is not None:
        from digail.sweep.search import run_search

        return run_search(spec, out, address=address, num_cpus=num_cpus, dashboard=dashboard)
    jobs = plan(spec)
    check_consistent(out, jobs)
    _require_ray()
    if all(job_done(out, j) for j in jobs):  # nothing to run: no Ray to start
        save_plan(out, spec, jobs)
        print(f"[sweep] {len(jobs)} jobs: all finished before", flush=True)
        return summarize_sweep(out)
    session = start_ray(address, num_cpus, dashboard, cpus_per_trial=spec.cpus_per_trial,
                        gpus_per_trial=spec.gpus_per_trial, resources_per_trial=dict(spec.resources_per_trial))
    try:
        save_plan(out, spec, jobs)
        execute(jobs, out, retries=spec.retries, cpus=spec.cpus_per_trial, gpus=spec.gpus_per_trial,
                resources=dict(spec.resources_per_trial), shared_fs=shared_fs, client=session.client,
                summary_every=summary_every)
    finally:
        stop_ray(session)
    return summarize_sweep(out)
