"""A sweep on a Ray cluster of three nodes on 127.0.0.1 (a head without CPUs, two workers with a custom resource),
each worker with its own working folder: trials land on both workers and work away from the driver's sweep folder,
one worker is removed mid-training, its trial resumes from its checkpoint on the other, and every number in
results.json equals the same sweep run on one machine."""

from __future__ import annotations

import contextlib
import json
import os
import signal
import tempfile
import threading
import time
from pathlib import Path

import pytest

from digail.sweep import load_plan, run_sweep, save_plan, summarize_sweep
from digail.sweep.engine import job_to_dict, read_state, run_job
from digail.sweep.plan import plan
from digail.sweep.spec import spec_from_dict

SPEC = {
    "name": "cluster",
    "envs": ["digail/CircleWorld-v0"],
    "methods": ["vae", "digail"],
    "seeds": [0],
    "preset": "smoke",
    "episodes": 3,
    "retries": 1,
    "resources_per_trial": {"worker": 1},
    "set": {"train.iterations": 30},
}
KILLED = "digail-CircleWorld-v0/digail_s0"


def _marked(folder: str) -> list[int]:
    marker = f"DIGAIL_RAY_SESSION={folder}".encode()
    out = []
    for entry in Path("/proc").iterdir():
        if entry.name.isdigit() and int(entry.name) != os.getpid():
            try:
                if marker in (entry / "environ").read_bytes().split(b"\0"):
                    out.append(int(entry.name))
            except OSError:
                continue
    return out


@pytest.fixture
def cluster():
    """Head (0 CPUs: no trial runs where the driver is) + two workers of 1 CPU and resource `worker`, each with its
    own TMPDIR (where a trial's scratch folder goes), all on 127.0.0.1 and torn down with every process."""
    ray = pytest.importorskip("ray")
    from ray.cluster_utils import Cluster

    from digail.sweep.cluster import SESSION_ENV, loopback_only

    loopback_only()
    root = tempfile.mkdtemp(prefix="dgc-")  # short: Ray's socket paths live under it
    os.environ[SESSION_ENV] = root  # every process of the cluster carries it: the teardown finds them all
    old_tmp = os.environ.get("RAY_TMPDIR")
    os.environ["RAY_TMPDIR"] = root  # where the head records its address, instead of Ray's default temporary folder
    (Path(root) / "ray").mkdir()
    os.environ.setdefault("MUJOCO_GL", "egl")
    workdirs = [Path(root) / f"node{i}" for i in (1, 2)]
    c = None
    try:
        c = Cluster(initialize_head=True, head_node_args={"num_cpus": 0, "temp_dir": root, "include_dashboard": False})
        nodes = []
        for w in workdirs:
            w.mkdir()
            nodes.append(c.add_node(num_cpus=1, resources={"worker": 1}, temp_dir=root, env_vars={"TMPDIR": str(w)}))
        ray.init(address=c.address, log_to_driver=False)
        yield c, nodes, workdirs
    finally:
        ray.shutdown()
        if c is not None:
            c.shutdown()
        del os.environ[SESSION_ENV]
        if old_tmp is None:
            del os.environ["RAY_TMPDIR"]
        else:
            os.environ["RAY_TMPDIR"] = old_tmp
        deadline = time.time() + 15
        while _marked(root) and time.time() < deadline:
            for pid in _marked(root):
                with contextlib.suppress(OSError):
                    os.kill(pid, signal.SIGKILL)
            time.sleep(0.5)
        import shutil

        shutil.rmtree(root, ignore_errors=True)


def _training_pid(scratch: Path) -> int | None:
    """The `digail train` process of the killed trial working in `scratch`, if it runs."""
    for entry in Path("/proc").iterdir():
        if entry.name.isdigit():
            try:
                argv = (entry / "cmdline").read_bytes().split(b"\0")
                cwd = os.readlink(entry / "cwd")
            except OSError:
                continue
            if b"train" in argv and KILLED.encode() in argv and cwd == str(scratch):
                return int(entry.name)
    return None


def _remove_mid_training(c, nodes, workdirs, sweep: Path, done: threading.Event, removed: list[str]) -> None:
    """Freeze the killed trial's training (SIGSTOP) as soon as it wrote a checkpoint in its scratch folder, so
    that it cannot finish however fast the machine; once that checkpoint has reached the driver's sweep folder,
    remove the node that runs it."""
    run = sweep / KILLED
    state_file = sweep / "trials" / (KILLED.replace("/", "__") + ".json")
    stopped = None
    while not done.is_set():
        if stopped is None:
            for ckpt in (p for w in workdirs for p in w.glob(f"digail-trial-*/{KILLED}/checkpoint.pt")):
                pid = _training_pid(ckpt.parents[2])
                if pid is not None:
                    os.kill(pid, signal.SIGSTOP)
                    stopped = pid
        elif (run / "checkpoint.pt").exists() and state_file.exists():
            with contextlib.suppress(ValueError):  # the state is replaced atomically, but read it twice if torn
                state = json.loads(state_file.read_text())
                if "train" in state.get("started", []) and state.get("node"):
                    [node] = [n for n in nodes if n.node_id == state["node"]]
                    c.remove_node(node, allow_graceful=False)
                    removed.append(state["node"])
                    return
        time.sleep(0.02)


@pytest.mark.slow  # three Ray nodes, four smoke stages twice (on the cluster and on one machine): a few minutes
def test_sweep_on_a_cluster_without_shared_folder_survives_a_lost_node_and_matches_one_machine(cluster, tmp_path):
    c, nodes, workdirs = cluster
    spec = spec_from_dict(SPEC)

    # the same sweep on one machine: every job's stages in order, in the folder itself (no Ray scheduling)
    ref = tmp_path / "ref"
    jobs = plan(spec)
    save_plan(ref, spec, jobs)
    for job in jobs:
        run_job(job_to_dict(job), str(ref))
    expected = summarize_sweep(ref)

    sweep = tmp_path / "sweep"
    done, removed = threading.Event(), []
    killer = threading.Thread(target=_remove_mid_training, args=(c, nodes, workdirs, sweep, done, removed), daemon=True)
    killer.start()
    try:
        result = run_sweep(spec, sweep, summary_every=5.0)
    finally:
        done.set()
    assert removed, "the trial finished before its node could be removed"

    assert result["failed"] == [] and result["done"] == result["trials"] == 2
    worker_ids = {n.node_id for n in nodes}
    ran_on: dict[str, list[str]] = {}
    for job in load_plan(sweep)[1]:
        state = read_state(sweep, job)
        assert state["status"] == "done", job.id
        ran_on[job.id] = state["nodes"]
        assert set(state["nodes"]) <= worker_ids, f"{job.id} ran on the head node"
        # every attempt worked in a scratch folder of its own node, never in the driver's sweep folder
        where = state["workdir"].split(" ", 2)[-1]
        node_dir = workdirs[[n.node_id for n in nodes].index(state["node"])]
        assert where.startswith(str(node_dir)) and not where.startswith(str(sweep)), (job.id, where)
    assert {n for ids in ran_on.values() for n in ids} == worker_ids, f"the trials did not spread: {ran_on}"

    # the trial on the removed node went on, on the other, from the checkpoint that had reached the driver
    first, second = ran_on[KILLED]
    assert first == removed[0] and second != first
    # scratch folders go with their attempt; only the attempt killed with its node left one (on that node's disk)
    left = {str(w): [p.name for p in w.glob("digail-trial-*")] for w in workdirs}
    lost = workdirs[[n.node_id for n in nodes].index(first)]
    assert sorted(len(v) for v in left.values()) == [0, 1] and len(left[str(lost)]) == 1, left
    killed = read_state(sweep, next(j for j in load_plan(sweep)[1] if j.id == KILLED))
    assert killed["attempts"] == 2 and f"digail train --resume {KILLED}" in killed["commands"]
    iters = [int(float(r.split(",")[1])) for r in (sweep / KILLED / "metrics.csv").read_text().splitlines()[1:]]
    assert iters[-1] == 30 and iters == sorted(set(iters)), "the resumed training repeated or skipped iterations"

    # the same numbers as on one machine, trial by trial
    for env, rows in expected["table"].items():
        for label, row in rows.items():
            for seed, rec in row["seeds"].items():
                got = result["table"][env][label]["seeds"][seed]
                assert got["metrics"] == rec["metrics"], (env, label, seed)
                assert got["env_steps"] == rec["env_steps"]
                assert got["metrics"], (env, label, seed)
