"""Hyper-parameter search: Optuna (TPE) through Ray Tune over a spec's range overrides.

`digail sweep --envs E --methods digail --seeds 0 1 --set train.bonus_weight=0.001..0.1:log --search optuna
--trials 16 --metric eval/normalized_return --out SWEEP`

Each Tune trial is one sampled setting (floats kept to 4 significant digits): it runs every (env, method, seed)
trial of the spec with those values, stage by stage as the grid sweep does (same run folders, named after the
sampled values, same state files, so a killed search resumes its runs), and reports the median over the trials of
the metric (`eval/<key of eval.json>` or `seg/<key of segmentation.json>`). Keys given several values become
categorical choices. When nothing searched changes the VAE, the VAEs are pre-trained once, before the search, and
shared. At the end `search.json` lists every sample (values, metric, runs) and the best, and results.json /
results.md hold a row per sample, as for a grid.
"""

from __future__ import annotations

import json
import math
from dataclasses import replace
from pathlib import Path
from typing import Any

import numpy as np

from digail.errors import UserError
from digail.sweep.cluster import start_ray, stop_ray
from digail.sweep.engine import check_consistent, execute, job_done, job_to_dict, run_job
from digail.sweep.plan import VAE_KEYS, Job, expand, plan
from digail.sweep.record import save_plan, summarize_sweep
from digail.sweep.spec import Range, SweepSpec, Value

SEARCH_FILE = "search.json"


def search_space(spec: SweepSpec) -> dict[str, Range | tuple[Value, ...]]:
    """The searched keys: ranges, and keys with several values (categorical)."""
    space: dict[str, Range | tuple[Value, ...]] = {}
    for grid in spec.grids:
        for key, values in grid.overrides:
            ranges = [v for v in values if isinstance(v, Range)]
            if ranges:
                if len(values) > 1:
                    raise UserError(f"{key}: give one range or a list of values, not both.")
                space[key] = ranges[0]
            elif len(values) > 1:
                space[key] = tuple(v for v in values if not isinstance(v, Range))
    if not space:
        raise UserError("a search needs something to search: give an override as a range, "
                        "e.g. --set train.bonus_weight=0.001..0.1:log.")
    return space


def tune_space(space: dict[str, Range | tuple[Value, ...]]) -> dict[str, Any]:
    """`search_space`'s dimensions as Ray Tune domains: (log-)uniform or (log-)integer ranges, or a choice."""
    from ray import tune

    out: dict[str, Any] = {}
    for key, dim in space.items():
        if isinstance(dim, Range):
            if dim.integer:
                out[key] = (tune.lograndint if dim.log else tune.randint)(int(dim.low), int(dim.high) + 1)
            else:
                out[key] = (tune.loguniform if dim.log else tune.uniform)(dim.low, dim.high)
        else:
            out[key] = tune.choice(list(dim))
    return out


def _fixed(spec: SweepSpec, values: dict[str, Any]) -> SweepSpec:
    """The spec with every searched key set to one sampled value."""
    grids = tuple(replace(g, overrides=tuple((k, (values[k],) if k in values else vals) for k, vals in g.overrides))
                  for g in spec.grids)
    return replace(spec, grids=grids, search=None)


def _rounded(config: dict[str, Any]) -> dict[str, Any]:
    return {k: float(f"{v:.4g}") if isinstance(v, float) else v for k, v in config.items()}


METRIC_FILES = {"eval": "eval.json", "seg": "segmentation.json"}


def check_metric(metric: str) -> tuple[str, str]:
    """(file, key) of a metric name, or a UserError."""
    source, _, key = metric.partition("/")
    if source not in METRIC_FILES or not key:
        raise UserError(f"metric {metric!r}: write eval/<key of eval.json> or seg/<key of segmentation.json>.")
    return METRIC_FILES[source], key


def metric_value(sweep: Path, job: Job, metric: str) -> float:
    """A trial's value of `metric` (eval/<key> or seg/<key>); NaN when it has none."""
    name, key = check_metric(metric)
    path = Path(sweep) / job.run / name
    value = json.loads(path.read_text()).get(key) if path.exists() else None
    return float(value) if isinstance(value, int | float) else math.nan


def sample_jobs(spec: SweepSpec, values: dict[str, Any], keys: tuple[str, ...]) -> list[Job]:
    """The jobs of one sampled setting, named after the sampled values."""
    fixed = _fixed(spec, values)
    return plan(fixed, expand(fixed), always_tag=keys)


def _trainable(config: dict[str, Any], spec: SweepSpec, sweep: str, keys: tuple[str, ...]) -> None:
    from ray import tune

    values = _rounded(config)
    jobs = sample_jobs(spec, values, keys)
    for job in jobs:  # VAEs first (shared ones are done already); stages resume like the grid's
        if not job_done(Path(sweep), job):
            run_job(job_to_dict(job), sweep, "tune")
    assert spec.search is not None
    scores = [metric_value(Path(sweep), j, spec.search.metric) for j in jobs if j.kind == "trial"]
    finite = [s for s in scores if math.isfinite(s)]
    score = float(np.median(finite)) if finite else math.nan
    tune.report({"objective": score, "runs": [j.run for j in jobs if j.kind == "trial"]})


def run_search(spec: SweepSpec, out: Path, *, address: str | None = None, num_cpus: int | None = None,
               dashboard: bool = False) -> dict[str, Any]:
    """Run the search of `spec` into the sweep folder `out`; returns the tables (with a `search` section)."""
    assert spec.search is not None
    if spec.search.mode not in ("max", "min"):
        raise UserError(f"search mode {spec.search.mode!r}: use max or min.")
    space = search_space(spec)
    keys = tuple(sorted(space))
    check_metric(spec.search.metric)
    try:
        from ray import tune
        from ray.tune.search.optuna import OptunaSearch
    except ImportError as exc:
        raise UserError("the search runs on Ray Tune and Optuna; pip install 'digail[sweep]'.") from exc
    session = start_ray(address, num_cpus, dashboard, cpus_per_trial=spec.cpus_per_trial,
                        gpus_per_trial=spec.gpus_per_trial)
    out.mkdir(parents=True, exist_ok=True)
    try:
        # VAEs that no searched key changes: pre-trained once, here, and shared by every sample
        if not any(k.startswith(VAE_KEYS) for k in keys):
            first = {k: (d.low if isinstance(d, Range) else d[0]) for k, d in space.items()}
            vaes = [j for j in sample_jobs(spec, first, keys) if j.kind == "vae"]
            check_consistent(out, vaes)
            execute(vaes, out, retries=spec.retries, cpus=spec.cpus_per_trial, gpus=spec.gpus_per_trial,
                    shared_fs=True)
        trainable = tune.with_resources(
            tune.with_parameters(_trainable, spec=spec, sweep=str(out), keys=keys),
            {"cpu": spec.cpus_per_trial, "gpu": spec.gpus_per_trial})
        storage = out / "tune"
        if tune.Tuner.can_restore(storage / "search"):
            tuner = tune.Tuner.restore(str(storage / "search"), trainable, resume_errored=True)
        else:
            tuner = tune.Tuner(
                trainable, param_space=tune_space(space),
                tune_config=tune.TuneConfig(search_alg=OptunaSearch(metric="objective", mode=spec.search.mode,
                                                                    seed=0),
                                            num_samples=spec.search.trials),
                run_config=tune.RunConfig(name="search", storage_path=str(storage), verbose=1,
                                          failure_config=tune.FailureConfig(max_failures=spec.retries)))
        grid = tuner.fit()
    finally:
        stop_ray(session)
    samples = []
    records: list[dict[str, Any]] = []
    for i in range(len(grid)):
        res = grid[i]
        values = _rounded({k: v for k, v in (res.config or {}).items() if k in space})
        score = (res.metrics or {}).get("objective")
        samples.append({"values": values, "metric": score if score is None or math.isfinite(score) else None,
                        "runs": (res.metrics or {}).get("runs", []),
                        "error": _one_line(res.error) if res.error else None})
        if values:
            records += expand(_fixed(spec, values))
    scored = [s for s in samples if s["metric"] is not None]
    best = (max if spec.search.mode == "max" else min)(scored, key=lambda s: s["metric"]) if scored else None
    summary = {"algo": spec.search.algo, "metric": spec.search.metric, "mode": spec.search.mode,
               "space": {k: str(d) if isinstance(d, Range) else list(d) for k, d in space.items()},
               "samples": samples, "best": best}
    (out / SEARCH_FILE).write_text(json.dumps(summary, indent=2, default=str) + "\n")
    if records:
        save_plan(out, spec, plan(spec, records, always_tag=keys))
    return summarize_sweep(out)


def _one_line(exc: BaseException) -> str:
    lines = str(exc).strip().splitlines()
    return f"{type(exc).__name__}: {lines[-1] if lines else ''}"
