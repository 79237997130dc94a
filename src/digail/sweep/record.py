"""The sweep folder's records: the plan of jobs (sweep.json) and the tables written from what the trials wrote.

Both the grid runner (the package) and the search runner (`digail.sweep.search`) write and read these, so they live
below both."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

from digail.errors import UserError
from digail.sweep.engine import job_from_dict, job_to_dict, read_json
from digail.sweep.plan import Job
from digail.sweep.spec import SweepSpec
from digail.sweep.summary import write_results

PLAN_FILE = "sweep.json"



def save_plan(out: Path, spec: SweepSpec, jobs: list[Job]) -> None:
    """Record the sweep's jobs (so --summarize needs only the folder)."""
    from dataclasses import asdict

    from digail.fsio import MARKER, write_marker

    out.mkdir(parents=True, exist_ok=True)
    if not (out / MARKER).exists():
        write_marker(out)
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
