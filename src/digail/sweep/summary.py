"""The tables of a sweep: `results.json` (every number, every command) and `results.md` (the medians).

Per env and method (a method's label names any setting that varies between the env's trials): every seed's metrics
- the trial's own `eval.json`, its run's `segmentation.json` as `seg/*`, `compose.json` as `compose/*` - with its env
steps, wall time and the `digail` commands that made it (the shared VAE's first); then the median and interquartile
range (25th and 75th percentiles) over the seeds of every numeric metric, and the trials that failed with their
errors.
"""

from __future__ import annotations

import json
import math
from pathlib import Path
from typing import Any

import numpy as np

from digail.sweep.engine import read_metrics_tail, read_state
from digail.sweep.plan import Job

HEADLINE = ("mean_return", "normalized_return", "success_rate", "path_length_ratio", "order_correct_rate",
            "radius_error", "dense_return", "grasp_rate", "seg/accuracy", "seg/nmi", "compose/order_reversed_rate")
"""metrics shown in results.md when a row has them (results.json has all)"""

SEG_KEYS = ("accuracy", "nmi", "boundary_f1", "switches_per_episode")


def _numbers(d: dict[str, Any], prefix: str = "") -> dict[str, float]:
    return {prefix + k: float(v) for k, v in d.items()
            if isinstance(v, int | float) and not isinstance(v, bool) and math.isfinite(float(v))}


def trial_record(sweep: Path, job: Job, vae: Job | None) -> dict[str, Any]:
    """One trial's numbers and provenance, read from its run folder and state."""
    sweep = Path(sweep)
    run = sweep / job.run
    state = read_state(sweep, job)
    rec: dict[str, Any] = {"seed": job.seed, "run": job.run, "status": state.get("status", "pending")}
    if state.get("error"):
        rec["error"] = state["error"]
    metrics: dict[str, float] = {}
    if (run / "eval.json").exists():
        ev = json.loads((run / "eval.json").read_text())
        metrics.update(_numbers(ev))
        if isinstance(ev.get("expert"), dict):
            metrics.update(_numbers(ev["expert"], "expert/"))
    if (run / "segmentation.json").exists():
        seg = json.loads((run / "segmentation.json").read_text())
        metrics.update({f"seg/{k}": v for k, v in _numbers(seg).items() if k in SEG_KEYS})
    if (run / "compose.json").exists():
        metrics.update(_numbers(json.loads((run / "compose.json").read_text()), "compose/"))
    rec["metrics"] = metrics
    tail = read_metrics_tail(run / "metrics.csv") if job.method != "vae" else {}
    rec["env_steps"] = int(tail.get("perf/global_step", 0))
    rec["wall_s"] = round(sum(s.get("wall_s", 0.0) for s in state.get("stages", {}).values()), 1)
    vae_state = read_state(sweep, vae) if vae is not None else {}
    if vae is not None:
        rec["vae_wall_s"] = round(sum(s.get("wall_s", 0.0) for s in vae_state.get("stages", {}).values()), 1)
    rec["commands"] = [*vae_state.get("commands", []), *state.get("commands", [])]
    return rec


def write_results(sweep: Path, jobs: list[Job], name: str = "") -> dict[str, Any]:
    """Write SWEEP/results.json and SWEEP/results.md; returns the JSON's content."""
    sweep = Path(sweep)
    by_id = {j.id: j for j in jobs}
    table: dict[str, dict[str, Any]] = {}
    failed = []
    for job in jobs:
        if job.kind != "trial":
            state = read_state(sweep, job)
            if state.get("status") == "failed":
                failed.append({"job": job.id, "error": state.get("error")})
            continue
        vae = by_id.get(job.deps[0]) if job.deps else None
        rec = trial_record(sweep, job, vae)
        if rec["status"] == "failed":
            failed.append({"job": job.id, "error": rec.get("error")})
        row = table.setdefault(job.env, {}).setdefault(job.label, {
            "method": job.method, "settings": {k: v for k, v in job.settings.items() if k != "demos"},
            "demos": job.settings.get("demos"), "seeds": {}})
        row["seeds"][str(job.seed)] = rec
    for rows in table.values():
        for row in rows.values():
            done = [r for r in row["seeds"].values() if r["metrics"] and r["status"] == "done"]
            keys = sorted({k for r in done for k in r["metrics"]})
            row["n"] = len(done)
            row["median"] = {k: float(np.median([r["metrics"][k] for r in done if k in r["metrics"]])) for k in keys}
            row["iqr"] = {k: [float(q) for q in np.percentile([r["metrics"][k] for r in done if k in r["metrics"]],
                                                               [25, 75])] for k in keys}
            row["env_steps"] = int(np.median([r["env_steps"] for r in done])) if done else 0
            row["wall_s"] = round(float(sum(r["wall_s"] for r in row["seeds"].values())), 1)
    result = {"sweep": str(sweep), "name": name, "trials": sum(j.kind == "trial" for j in jobs),
              "done": sum(r["status"] == "done" for rows in table.values() for row in rows.values()
                          for r in row["seeds"].values()),
              "failed": failed, "table": table}
    (sweep / "results.json").write_text(json.dumps(result, indent=2) + "\n")
    (sweep / "results.md").write_text(markdown(result))
    return result


def _cell(row: dict[str, Any], key: str) -> str:
    if key not in row["median"]:
        return ""
    lo, hi = row["iqr"][key]
    med = row["median"][key]
    return f"{_fmt(med)} [{_fmt(lo)}, {_fmt(hi)}]" if row["n"] > 1 else _fmt(med)


def _fmt(x: float) -> str:
    return f"{x:.3g}" if abs(x) < 1000 else f"{x:,.0f}"


def markdown(result: dict[str, Any]) -> str:
    """The Markdown tables of a summary: per env a row per method, median [IQR] over seeds."""
    lines = [f"# Sweep {result['name'] or result['sweep']}", "",
             f"{result['done']} of {result['trials']} trials done; cells are median [25th, 75th percentile] over "
             "seeds (`results.json` has every seed and the commands).", ""]
    for env, rows in result["table"].items():
        cols = [k for k in HEADLINE if any(k in row["median"] for row in rows.values())]
        lines += [f"## {env}", "", "| method | seeds | " + " | ".join(cols) + " | env steps | wall |",
                  "| --- | --- | " + " | ".join("---" for _ in cols) + " | --- | --- |"]
        for label, row in rows.items():
            seeds = f"{row['n']}/{len(row['seeds'])}"
            cells = " | ".join(_cell(row, k) for k in cols)
            lines.append(f"| {label} | {seeds} | {cells} | {row['env_steps']:,} | {row['wall_s']:,.0f} s |")
        lines.append("")
    if result["failed"]:
        lines += ["## Failed", ""] + [f"- `{f['job']}`: {f['error']}" for f in result["failed"]] + [""]
    return "\n".join(lines)
