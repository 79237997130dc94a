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

import json
from pathlib import Path
from typing import Any

from digail.errors import UserError
from digail.sweep.cluster import start_ray, stop_ray
from digail.sweep.engine import check_consistent, execute, job_done, job_from_dict, job_to_dict, read_json
from digail.sweep.plan import Job, plan
from digail.sweep.spec import Grid, Range, SearchSpec, SweepSpec, load_spec, parse_set
from digail.sweep.summary import write_results

__all__ = ["Grid", "Range", "SearchSpec", "SweepSpec", "load_spec", "parse_set", "plan", "run_sweep", "start_ray",
           "stop_ray", "summarize_sweep"]

PLAN_FILE = "sweep.json"


def _require_ray() -> None:
    try:
        import ray  # noqa: F401
    except ImportError as exc:
        raise UserError("sweeps run on Ray, which is not installed; pip install 'digail[sweep]'.") from exc


def save_plan(out: Path, spec: SweepSpec, jobs: list[Job]) -> None:
    """Record the sweep's jobs (so --summarize needs only the folder)."""
    from dataclasses import asdict

    out.mkdir(parents=True, exist_ok=True)
    (out / PLAN_FILE).write_text(json.dumps({"name": spec.name, "spec": asdict(spec),
                                             "jobs": [job_to_dict(j) for j in jobs]}, indent=2, default=str) + "\n")


def load_plan(out: Path) -> tuple[str, list[Job]]:
    """The jobs recorded in a sweep folder."""
    path = Path(out) / PLAN_FILE
    if not path.exists():
        raise UserError(f"{out} is not a sweep folder (no {PLAN_FILE}); pass the --out of a `digail sweep`.")
    data = read_json(path, "the sweep's plan; run the `digail sweep` command again to rewrite it")
    try:
        return data.get("name", ""), [job_from_dict(j) for j in data["jobs"]]
    except (AttributeError, KeyError, TypeError) as exc:
        raise UserError(f"{path} does not hold a sweep's plan ({type(exc).__name__}: {exc}); run the `digail sweep` "
                        "command again to rewrite it.") from None


def check_out(out: Path) -> None:
    """Refuse a sweep folder that is a file (or under one)."""
    for parent in (out, *out.parents):
        if parent.exists() and not parent.is_dir():
            raise UserError(f"{parent} is a file, not a folder; pass a folder (new or a sweep's) to --out.")


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


def summarize_sweep(out: Path | str) -> dict[str, Any]:
    """(Re)write SWEEP/results.json and results.md from what the trials wrote; returns the JSON's content."""
    out = Path(out).resolve()
    name, jobs = load_plan(out)
    result = write_results(out, jobs, name)
    search_file = out / "search.json"
    if search_file.exists():
        result["search"] = search = read_json(search_file, "the search's samples")
        (out / "results.json").write_text(json.dumps(result, indent=2) + "\n")
        scored = sorted((s for s in search["samples"] if s["metric"] is not None), key=lambda s: s["metric"],
                        reverse=search["mode"] == "max")
        lines = [f"## Search ({search['algo']}, {search['mode']} {search['metric']}, median over seeds)", "",
                 "| " + " | ".join(search["space"]) + f" | {search['metric']} |",
                 "| " + " | ".join("---" for _ in search["space"]) + " | --- |"]
        lines += ["| " + " | ".join(str(s["values"].get(k)) for k in search["space"]) + f" | {s['metric']:.4g} |"
                  for s in scored]
        with open(out / "results.md", "a") as f:
            f.write("\n".join(lines) + "\n")
    return result
