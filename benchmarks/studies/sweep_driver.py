"""How many trials one `digail sweep` driver moves through Ray per second when the trials themselves cost nothing.

    python benchmarks/studies/sweep_driver.py [--trials 200] [--cpus 2] [--remote]
        [--out benchmarks/studies/results/sweep_driver.json]

Plans a sweep of `--trials` VAE-baseline trials (CircleWorld, one seed each, so `--trials` VAE jobs and as many
evaluations), and runs it with the real driver (`digail.sweep.engine.execute`: scheduling, dependencies, state
files, polling, summaries) on a local Ray of `--cpus` CPUs, each trial's task replaced by a stand-in that writes the
state and a small eval.json a real trial would. `--remote` sends every trial through the no-shared-folder path
(inputs packed by the driver, outputs packed back and unpacked), as for a trial on another node. Writes the wall
time, trials per second and driver CPU seconds per trial to `--out`; the summary table is built too and timed.
"""

from __future__ import annotations

import argparse
import json
import resource
import tempfile
import time
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parents[2]


def stand_in(job_dict: dict[str, Any], sweep: str, token: str = "",
             transfer: dict[str, Any] | None = None) -> dict[str, Any]:
    """A trial that does no work: the files a finished stage leaves, through the same folder handling as run_job."""
    import ray

    from digail.sweep import transfer as tr
    from digail.sweep.engine import job_from_dict, job_outputs, write_state

    job = job_from_dict(job_dict)
    remote = transfer is not None and "inputs" in transfer and transfer.get("remote")
    root = tr.scratch_dir() if remote else Path(sweep)
    if remote:
        assert transfer is not None
        tr.unpack(ray.get(transfer["inputs"]) if isinstance(transfer["inputs"], ray.ObjectRef)
                  else transfer["inputs"], root)
    state = {"status": "done", "token": token, "commands": [], "error": None, "todo": [s.name for s in job.stages],
             "stages": {s.name: {"argv": list(s.argv), "rc": 0, "wall_s": 0.0} for s in job.stages}}
    (root / job.run).mkdir(parents=True, exist_ok=True)
    if job.kind == "trial":
        (root / job.run / "eval.json").write_text(json.dumps({"mean_return": float(job.seed), "episodes": 1}))
    write_state(root, job, state)
    if remote:
        state["pack"] = tr.pack(root, job_outputs(job))
        tr.remove(root)
    return state


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--trials", type=int, default=200)
    parser.add_argument("--cpus", type=int, default=2)
    parser.add_argument("--remote", action="store_true")
    parser.add_argument("--out", type=Path, default=ROOT / "benchmarks" / "studies" / "results" / "sweep_driver.json")
    args = parser.parse_args()

    from digail.sweep import save_plan, start_ray, stop_ray, summarize_sweep
    from digail.sweep.engine import execute
    from digail.sweep.plan import plan
    from digail.sweep.spec import Grid, SweepSpec

    spec = SweepSpec(grids=(Grid(envs=("digail/CircleWorld-v0",), methods=("vae",), seeds=tuple(range(args.trials)),
                                 preset="smoke", episodes=1),))
    jobs = plan(spec)
    with tempfile.TemporaryDirectory(prefix="sweep-driver-") as folder:
        sweep = Path(folder)
        save_plan(sweep, spec, jobs)
        session = start_ray(num_cpus=args.cpus)
        try:
            import ray

            if args.remote:  # every task as one on another node: the driver packs, the task unpacks and packs
                task: Any = lambda job_dict, sweep, token="", transfer=None: stand_in(  # noqa: E731
                    job_dict, sweep, token, {**(transfer or {}), "remote": True})
            else:
                task = stand_in
            ray.get(ray.remote(lambda: 0).remote())  # a warm worker: Ray's start is not the driver's cost
            cpu0, t0 = resource.getrusage(resource.RUSAGE_SELF), time.perf_counter()
            states = execute(jobs, sweep, retries=0, summary_every=3600, log=lambda _: None, task=task)
            wall = time.perf_counter() - t0
            cpu1 = resource.getrusage(resource.RUSAGE_SELF)
        finally:
            stop_ray(session)
        t1 = time.perf_counter()
        result = summarize_sweep(sweep)
        summary_s = time.perf_counter() - t1
    driver_cpu = (cpu1.ru_utime + cpu1.ru_stime) - (cpu0.ru_utime + cpu0.ru_stime)
    n_jobs = len(jobs)
    out = {"trials": args.trials, "jobs": n_jobs, "ray_cpus": args.cpus, "remote": args.remote,
           "done": sum(s["status"] == "done" for s in states.values()), "table_done": result["done"],
           "wall_s": round(wall, 2), "jobs_per_s": round(n_jobs / wall, 2),
           "driver_cpu_s_per_job": round(driver_cpu / n_jobs, 4), "summary_s": round(summary_s, 2)}
    print(json.dumps(out, indent=2))
    args.out.write_text(json.dumps(out, indent=2) + "\n")


if __name__ == "__main__":
    main()
