"""SIGTERM and SIGINT during `digail run`: no temporary folder left, exit 128 + signal, and `--resume` finishes
the pipeline with the numbers of an uninterrupted run (Four Rooms, SMOKE)."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest
import torch

from digail.cli import main

ENV = "digail/FourRooms-v0"
ARGS = [ENV, "--preset", "smoke", "--episodes", "3"]


@pytest.fixture(scope="module")
def reference(tmp_path_factory) -> Path:
    """The uninterrupted run."""
    run = tmp_path_factory.mktemp("signals") / "reference"
    assert main(["run", *ARGS, "--out", str(run)]) == 0
    return run


def _interrupt(run: Path, sig: signal.Signals, when: str) -> None:
    """Start `digail run` in a subprocess, send `sig` once `when` exists in the run folder, check the ending."""
    env = {**os.environ, "PYTHONUNBUFFERED": "1", "MUJOCO_GL": "egl"}
    proc = subprocess.Popen([sys.executable, "-m", "digail.cli", "run", *ARGS, "--out", str(run)],
                            stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True, env=env)
    deadline = time.time() + 240
    while time.time() < deadline and proc.poll() is None and not (run / when).exists():
        time.sleep(0.02)
    assert proc.poll() is None, "the run ended before it could be interrupted"
    proc.send_signal(sig)
    _, err = proc.communicate(timeout=120)
    assert proc.returncode == 128 + sig, err[-2000:]
    assert f"stopped by {sig.name}" in err and "--resume" in err
    assert not list(run.parent.glob(".*.tmp-*")) and not list(run.rglob(".*.tmp-*")), "a temporary folder was left"


def _same_results(run: Path, reference: Path) -> None:
    for name in ("eval.json", "segmentation.json"):
        got, want = json.loads((run / name).read_text()), json.loads((reference / name).read_text())
        want = {k: v for k, v in want.items() if "time" not in k}
        assert {k: got[k] for k in want} == want, name
    a = torch.load(run / "checkpoint.pt", weights_only=True)
    b = torch.load(reference / "checkpoint.pt", weights_only=True)
    assert a["iteration"] == b["iteration"] and a["global_step"] == b["global_step"]
    for part in ("model", "value", "disc"):
        assert all(torch.equal(a[part][k], b[part][k]) for k in b[part]), part
    steps = [line.split(",")[0] for line in (run / "metrics.csv").read_text().splitlines()[1:]]
    assert len(steps) == len(set(steps)), "metrics.csv repeats a step"


def test_sigterm_during_pretraining_then_resume(reference, tmp_path):
    run = tmp_path / "run"
    _interrupt(run, signal.SIGTERM, "vae")
    assert not (run / "vae" / "model.pt").exists()
    assert main(["run", "--resume", str(run)]) == 0
    _same_results(run, reference)


def test_sigint_after_pretraining_then_resume_from_elsewhere(reference, tmp_path, monkeypatch):
    run = tmp_path / "run"
    _interrupt(run, signal.SIGINT, "vae/model.pt")
    monkeypatch.chdir(tmp_path.parent)  # paths in config.json are absolute: any working directory resumes
    assert main(["run", "--resume", str(run)]) == 0
    _same_results(run, reference)
