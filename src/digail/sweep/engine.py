"""Running a sweep's jobs on Ray: one task per job, each stage a `digail` subprocess, resumable and retried.

The driver (the `digail sweep` process) keeps the schedule: it submits every job whose VAE is ready as a Ray task
declaring its CPUs (and GPUs), waits on them, prints a line per state change and a live summary, retries a failed
job up to `retries` times and then records its error without stopping the others. A job's task runs the stages it
has not finished, as `python -m digail.cli STAGE ...` in the sweep folder, exactly what a user would type; a training
stage whose folder holds a checkpoint continues with `digail train --resume`. Every finished stage is recorded in
`trials/<job>.json` by the task itself, so whatever is killed (the stage, the Ray worker, the node, the driver), the
next attempt or the next `digail sweep` call picks up from there.

On a cluster, digail (with its demonstrations) must be installed on every node; the sweep folder need not be
shared. A trial on another node than the driver's works in a scratch folder of its own, receiving and returning
its folders through Ray (`digail.sweep.transfer`); with `shared_fs` (the sweep folder is at the same path on every
node) it works in the sweep folder itself, as a trial on the driver's node always does.
"""

from __future__ import annotations

import contextlib
import csv
import json
import os
import shlex
import subprocess
import sys
import time
from collections.abc import Callable
from dataclasses import asdict
from pathlib import Path
from typing import Any

from digail.errors import UserError
from digail.sweep.plan import Job, Stage
from digail.utils import die_with_parent

STATE_DIR = "trials"
LOG_DIR = "logs"


# ------------------------------------------------------------------------------------------------ state
def state_path(sweep: Path, job: Job | str) -> Path:
    """Where a job's state lives."""
    fid = job.file_id if isinstance(job, Job) else job.replace("/", "__")
    return Path(sweep) / STATE_DIR / f"{fid}.json"


def read_state(sweep: Path, job: Job | str) -> dict[str, Any]:
    """A job's state (an empty pending one if it never ran)."""
    path = state_path(sweep, job)
    if not path.exists():
        return {"status": "pending", "attempts": 0, "stages": {}, "commands": [], "error": None}
    return read_json(path, "the trial's state; delete it to run that trial again")


def read_json(path: Path, what: str) -> Any:
    """A JSON file of the sweep folder, or a UserError naming it when it is cut short or corrupt."""
    try:
        return json.loads(path.read_text())
    except (json.JSONDecodeError, UnicodeDecodeError) as exc:
        raise UserError(f"{path} is not valid JSON ({exc.__class__.__name__} at {getattr(exc, 'pos', '?')}); it "
                        f"holds {what}.") from None


def write_state(sweep: Path, job: Job, state: dict[str, Any]) -> None:
    """Atomically write a job's state."""
    path = state_path(sweep, job)
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(f".{path.name}.{os.getpid()}.tmp")
    tmp.write_text(json.dumps({"id": job.id, "env": job.env, "method": job.method, "seed": job.seed,
                               "run": job.run, "label": job.label, "settings": job.settings, **state},
                              indent=2, default=str) + "\n")
    os.replace(tmp, path)


def stage_done(state: dict[str, Any], stage: Stage) -> bool:
    """Whether `stage` finished with exactly these arguments."""
    rec = state.get("stages", {}).get(stage.name)
    return bool(rec) and rec.get("rc") == 0 and tuple(rec.get("argv", ())) == stage.argv


def job_done(sweep: Path, job: Job) -> bool:
    """Whether every stage of `job` finished (with the arguments it has now)."""
    state = read_state(sweep, job)
    return all(stage_done(state, s) for s in job.stages)


def check_consistent(sweep: Path, jobs: list[Job]) -> None:
    """Refuse to mix settings: a finished training (or VAE) run with other arguments than the plan's."""
    for job in jobs:
        state = read_state(sweep, job)
        for stage in job.stages:
            rec = state.get("stages", {}).get(stage.name)
            if stage.name in ("pretrain", "train") and rec and rec.get("rc") == 0 and tuple(rec["argv"]) != stage.argv:
                raise UserError(f"{Path(sweep) / stage.run} was made by `digail {shlex.join(rec['argv'])}`, not by "
                                f"this sweep's `digail {shlex.join(stage.argv)}`; use another --out for other "
                                "settings.")


# ------------------------------------------------------------------------------------------ the Ray task
def _resolve_argv(sweep: Path, stage: Stage) -> tuple[str, ...]:
    if stage.labels is None:
        return stage.argv
    from digail.eval.composition import schedule_in_codes

    seg = json.loads((sweep / stage.mapping_from / "segmentation.json").read_text())
    pairs = tuple((int(a), int(b)) for a, b in (p.split(":") for p in stage.labels.split(",")))
    schedule = schedule_in_codes(pairs, seg.get("mapping", {}))
    if schedule is None:
        raise RuntimeError(f"{stage.mapping_from}: the segmentation gave no code of its own to each sub-task; "
                           "nothing to compose")
    return tuple(schedule if a == "{schedule}" else a for a in stage.argv)


def _tail(log: Path, start: int, lines: int = 3) -> str:
    """The last non-empty lines a stage wrote to its log (progress bars reduced to their last state)."""
    with open(log, "rb") as f:
        f.seek(start)
        text = f.read().decode(errors="replace")
    rows = [ln.rsplit("\r", 1)[-1].strip(" │╭╮╰╯─\t") for ln in text.splitlines()]  # tyro draws boxes
    rows = [r for r in rows if r and not r.startswith("For full helptext")] or ["(no output)"]
    return " ".join(rows[-lines:])


def _newline_if_needed(log: Path) -> str:
    if not log.exists() or log.stat().st_size == 0:
        return ""
    with open(log, "rb") as f:
        f.seek(-1, os.SEEK_END)
        return "" if f.read(1) == b"\n" else "\n"


def run_job(job_dict: dict[str, Any], sweep: str, token: str = "",
            transfer: dict[str, Any] | None = None) -> dict[str, Any]:
    """Run a job's unfinished stages one after another; returns its state. Raises RuntimeError on a failed stage.

    `token` names this attempt: written into the state as the task starts, it tells the driver the task left
    Ray's queue (no clocks compared across nodes). `transfer` (from the driver) carries the job's input folders
    packed and the mailbox: used when this task runs on another node than the driver's, where it works in a
    scratch folder and sends its folders back (see `digail.sweep.transfer`); the result then carries the final
    pack under `"pack"`."""
    job = job_from_dict(job_dict)
    node = _node_id()
    remote = transfer is not None and not transfer.get("shared_fs") and node != transfer.get("driver_node")
    if not remote:
        return _run_stages(job, Path(sweep), token, node, "sweep folder")
    assert transfer is not None
    import ray

    from digail.sweep import transfer as tr

    work = tr.scratch_dir()
    try:
        tr.unpack(ray.get(transfer["inputs"]) if isinstance(transfer["inputs"], ray.ObjectRef)
                  else transfer["inputs"], work)
        outputs = job_outputs(job)
        mailbox = transfer["mailbox"]

        def send() -> None:
            ray.get(mailbox.put.remote(job.id, tr.pack(work, outputs)))

        try:
            state = _run_stages(job, work, token, node, "scratch folder", on_change=send)
        finally:
            with contextlib.suppress(Exception):
                send()  # the last state (and the failed stage's log) reach the driver too
        return {**state, "pack": tr.pack(work, outputs)}
    finally:
        tr.remove(work)


def job_inputs(job: Job, by_id: dict[str, Job]) -> list[str]:
    """Paths (relative to the sweep folder) a job's task reads: its outputs and its dependencies' run folders."""
    paths = job_outputs(job) + [by_id[d].run for d in job.deps if d in by_id]
    paths += [s.mapping_from for s in job.stages if s.mapping_from]
    return list(dict.fromkeys(paths))


def job_outputs(job: Job) -> list[str]:
    """Paths a job's task writes: its run folder, state and log."""
    return [job.run, f"{STATE_DIR}/{job.file_id}.json", f"{LOG_DIR}/{job.file_id}.log"]


def _node_id() -> str | None:
    with contextlib.suppress(Exception):
        import ray

        if ray.is_initialized():
            return str(ray.get_runtime_context().get_node_id())
    return None


def _run_stages(job: Job, root: Path, token: str, node: str | None, where: str,
                on_change: Callable[[], None] | None = None) -> dict[str, Any]:
    log = root / LOG_DIR / f"{job.file_id}.log"
    log.parent.mkdir(parents=True, exist_ok=True)
    state = read_state(root, job)
    state["status"] = "running"
    state["started_at"] = time.time()
    state["token"] = token
    state["todo"] = [s.name for s in job.stages if not stage_done(state, s)]
    state["resuming"] = next((s for s in state["todo"] if s in state.get("started", [])), None)
    state["host"] = os.uname().nodename
    state["node"] = node
    state.setdefault("nodes", []).append(node)
    state["workdir"] = f"{where} {root}"
    write_state(root, job, state)
    if on_change is not None:
        on_change()
    env = {**os.environ, "PYTHONUNBUFFERED": "1"}  # the digail CLI picks MUJOCO_GL itself when it is unset
    for stage in job.stages:
        if stage_done(state, stage):
            continue
        argv = _resolve_argv(root, stage)
        run_dir = root / stage.run
        remove_temporaries(run_dir)  # what a killed attempt of this stage left
        resumed = stage.resume is not None and (run_dir / "checkpoint.pt").exists() and (
            run_dir / "config.json").exists() and stage.name in state.get("started", [])
        actual = stage.resume if resumed and stage.resume is not None else argv
        line = "digail " + shlex.join(actual)
        state.setdefault("commands", []).append(line)
        state.setdefault("started", [])
        if stage.name not in state["started"]:
            state["started"].append(stage.name)
        write_state(root, job, state)
        t0 = time.time()
        with open(log, "ab") as f:
            start = f.tell()
            f.write(f"{_newline_if_needed(log)}$ {line}\n".encode())  # a killed progress bar left none
            f.flush()
            proc = subprocess.Popen([sys.executable, "-m", "digail.cli", *actual], cwd=root, env=env, stdout=f,
                                    stderr=subprocess.STDOUT, preexec_fn=die_with_parent)
            rc = _wait(proc, run_dir / "checkpoint.pt", on_change)
        wall = time.time() - t0
        prev = state["stages"].get(stage.name, {})
        rec = {"argv": list(argv), "rc": rc, "wall_s": prev.get("wall_s", 0.0) + wall, "resumed": resumed}
        state["stages"][stage.name] = rec
        if rc != 0:
            why = f"killed by signal {-rc}" if rc < 0 else f"exit status {rc}"
            state["error"] = f"digail {stage.name} ({why}): {_tail(log, start)}"
            write_state(root, job, state)
            raise RuntimeError(state["error"])
        state["error"] = None
        write_state(root, job, state)
        if on_change is not None:
            on_change()
    state["status"] = "done"
    write_state(root, job, state)
    return state


def _wait(proc: subprocess.Popen[bytes], checkpoint: Path, on_change: Callable[[], None] | None,
          every: float = 2.0) -> int:
    """Wait for a stage's process; while it runs, call `on_change` whenever its checkpoint is rewritten."""
    if on_change is None:
        return proc.wait()
    seen = None
    while True:
        try:
            return proc.wait(timeout=every)
        except subprocess.TimeoutExpired:
            pass
        with contextlib.suppress(OSError):
            stamp = checkpoint.stat().st_mtime_ns
            if stamp != seen:
                seen = stamp
                on_change()


def job_to_dict(job: Job) -> dict[str, Any]:
    """A Job as plain data (what travels to the Ray worker)."""
    return asdict(job)


def job_from_dict(data: dict[str, Any]) -> Job:
    """The inverse of `job_to_dict`."""
    stages = tuple(Stage(**{**s, "argv": tuple(s["argv"]),
                            "resume": tuple(s["resume"]) if s.get("resume") else None}) for s in data["stages"])
    return Job(**{**data, "stages": stages, "deps": tuple(data["deps"])})


# ------------------------------------------------------------------------------------------------ Ray
def _running_sps(sweep: Path, jobs: list[Job]) -> float:
    """Environment steps per second of the running trainings: their latest `perf/sps`."""
    total = 0.0
    for job in jobs:
        path = Path(sweep) / job.run / "metrics.csv"
        if not path.exists():
            continue
        with contextlib.suppress(Exception), open(path) as f:
            header = f.readline().strip().split(",")
            f.seek(max(0, path.stat().st_size - 4096))
            last = f.read().strip().splitlines()[-1].split(",")
            if "perf/sps" in header and len(last) == len(header):
                value = float(last[header.index("perf/sps")])
                total += value if value == value else 0.0
    return total


def execute(jobs: list[Job], sweep: Path, *, retries: int = 1, cpus: float = 1.0, gpus: float = 0.0,
            resources: dict[str, float] | None = None, shared_fs: bool = False, client: bool = False,
            summary_every: float = 30.0, log: Callable[[str], None] | None = None,
            task: Callable[..., dict[str, Any]] | None = None) -> dict[str, dict[str, Any]]:
    """Run `jobs` on the initialised Ray (dependencies first); returns every job's final state by id.

    A job whose dependency failed is reported failed without running. Ctrl-C cancels the running tasks (their
    stages die with them) and re-raises; the next call resumes. Trials on other nodes than the driver's get and
    return their folders through Ray unless `shared_fs`; `client`: the driver is a Ray Client, on no node.
    `task` is what a job's Ray task runs (`run_job`, with its arguments; the driver benchmark passes a stand-in)."""
    import ray

    from digail.sweep import transfer as tr

    out = log or (lambda msg: print(msg, flush=True))
    sweep = Path(sweep)
    remote = ray.remote(task or run_job).options(num_cpus=cpus, num_gpus=gpus, resources=resources or None,
                                                 max_retries=0)
    driver_node = None if client else _node_id()
    mailbox = None if shared_fs else tr.mailbox_actor(driver_node)
    by_id = {j.id: j for j in jobs}
    states: dict[str, dict[str, Any]] = {}
    waiting: list[Job] = []
    for job in jobs:
        if job_done(sweep, job):
            states[job.id] = {**read_state(sweep, job), "status": "done"}
        else:
            waiting.append(job)
    skipped = len(states)
    out(f"[sweep] {len(jobs)} jobs: {skipped} finished before, {len(waiting)} to run "
        f"(Ray: {ray.cluster_resources().get('CPU', 0):g} CPUs, {cpus:g} per trial)")
    running: dict[Any, tuple[Job, float]] = {}
    started: set[str] = set()  # submitted jobs whose task has begun (the rest wait in Ray's queue for a CPU)
    attempts: dict[str, int] = {}
    tokens: dict[str, str] = {}
    t_start = time.time()
    last_summary = 0.0

    def summary(force: bool = False) -> None:
        nonlocal last_summary
        if not force and time.time() - last_summary < summary_every:
            return
        last_summary = time.time()
        done = sum(s["status"] == "done" for s in states.values())
        failed = sum(s["status"] == "failed" for s in states.values())
        sps = _running_sps(sweep, [j for j, _ in running.values()])
        n_run = sum(j.id in started for j, _ in running.values())
        out(f"[sweep] {done}/{len(jobs)} done, {n_run} running, {len(running) - n_run} queued, {failed} failed, "
            f"{len(waiting)} waiting | {sps:,.0f} env steps/s | {time.time() - t_start:,.0f}s")

    def poll_started() -> None:
        for job, _ in running.values():
            if job.id not in started and read_state(sweep, job).get("token") == tokens[job.id]:
                started.add(job.id)
                state = read_state(sweep, job)
                extra = f" (resuming {state['resuming']})" if state.get("resuming") else ""
                out(f"[sweep] run    {job.id} on {state.get('host', '?')}: {' -> '.join(state['todo'])}{extra}")

    def submit(job: Job) -> None:
        attempts[job.id] = attempts.get(job.id, 0) + 1
        tokens[job.id] = f"{os.getpid()}-{time.time()}-{attempts[job.id]}"
        transfer = {"shared_fs": True} if mailbox is None else {
            "driver_node": driver_node, "mailbox": mailbox,
            "inputs": ray.put(tr.check_pack_size(tr.pack(sweep, job_inputs(job, by_id)), job.id))}
        ref = remote.remote(job_to_dict(job), str(sweep), tokens[job.id], transfer)
        running[ref] = (job, time.time())
        started.discard(job.id)
        states[job.id] = {"status": "queued"}
        out(f"[sweep] queue  {job.id} (attempt {attempts[job.id]}/{retries + 1})")

    def schedule() -> None:
        for job in list(waiting):
            deps = [states.get(d, {}).get("status") for d in job.deps]
            if any(d == "failed" for d in deps):
                waiting.remove(job)
                err = f"its VAE job {job.deps[0]} failed"
                state = {**read_state(sweep, job), "status": "failed", "error": err}
                write_state(sweep, job, state)
                states[job.id] = state
                out(f"[sweep] failed {job.id}: {err}")
            elif all(d == "done" for d in deps):
                waiting.remove(job)
                submit(job)

    def collect() -> None:
        """Unpack what trials on other nodes sent since the last call (before their results are read, which are
        newer)."""
        if mailbox is not None:
            for data in ray.get(mailbox.take.remote()).values():
                tr.unpack(data, sweep)

    try:
        schedule()
        while running:
            ready, _ = ray.wait(list(running), num_returns=1, timeout=min(summary_every, 2.0))
            collect()
            poll_started()
            for ref in ready:
                job, _ = running.pop(ref)
                try:
                    state = ray.get(ref)
                    if "pack" in state:
                        tr.unpack(state.pop("pack"), sweep)
                except Exception as exc:  # a failed stage, a lost worker or node: retried alike
                    err = read_state(sweep, job).get("error") or _one_line(exc)
                    if attempts[job.id] <= retries:
                        out(f"[sweep] retry  {job.id}: {err}")
                        submit(job)
                        continue
                    state = {**read_state(sweep, job), "status": "failed", "error": err,
                             "attempts": attempts[job.id]}
                    write_state(sweep, job, state)
                    states[job.id] = state
                    out(f"[sweep] failed {job.id} after {attempts[job.id]} attempt(s): {err}")
                else:
                    state["attempts"] = attempts[job.id]
                    write_state(sweep, job, state)
                    states[job.id] = state
                    took = time.time() - state.get("started_at", time.time())
                    out(f"[sweep] done   {job.id} ({took:.0f}s)")
                schedule()
                summary(force=True)
            summary()
    except KeyboardInterrupt as exc:
        from digail.sweep.cluster import reraise_signal

        for ref in running:
            with contextlib.suppress(Exception):
                ray.cancel(ref, force=True)
        # a stage killed with its worker cannot remove its own temporary folder (a VAE's `.vae_s0.tmp-*`)
        time.sleep(0.5)
        for job, _ in running.values():
            remove_temporaries(sweep / job.run)
        out("[sweep] interrupted: the running stages were stopped; run the same command again to resume.")
        reraise_signal(exc)
    for job in waiting:  # only when a dependency never finished (cannot happen, kept for safety)
        states[job.id] = {"status": "failed", "error": "not run: its dependencies did not finish"}
    return {jid: states.get(jid, {"status": "pending"}) for jid in by_id}


def remove_temporaries(run_dir: Path) -> None:
    """Remove the temporary siblings a stage writing `run_dir` atomically makes (`.NAME.tmp-*`, `.NAME.old-*`,
    see `digail.fsio.atomic_dir`): a stage killed outright (SIGKILL, Ray's cancel) leaves them behind."""
    import glob
    import shutil

    pattern = glob.escape(str(Path(run_dir).parent / f".{Path(run_dir).name}."))
    for path in glob.glob(pattern + "tmp-*") + glob.glob(pattern + "old-*"):
        shutil.rmtree(path, ignore_errors=True)


def _one_line(exc: BaseException) -> str:
    text = str(exc).strip().splitlines()
    return f"{type(exc).__name__}: {text[-1] if text else ''}"


def read_metrics_tail(path: Path) -> dict[str, float]:
    """The last row of a run's metrics.csv as numbers ({} when there is none)."""
    if not path.exists():
        return {}
    with open(path) as f:
        rows = list(csv.DictReader(f))
    if not rows:
        return {}
    out = {}
    for k, v in rows[-1].items():
        with contextlib.suppress(TypeError, ValueError):
            out[k] = float(v)
    return out
