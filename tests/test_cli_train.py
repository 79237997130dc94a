"""The training commands end to end on SMOKE settings, their bad input, and a SIGKILL + resume."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time

import pytest
import torch

from digail.checkpoint import load_model
from digail.cli import main

ENV = "digail/CircleWorld-v0"


@pytest.fixture(scope="module")
def smoke_runs(tmp_path_factory):
    root = tmp_path_factory.mktemp("cli")
    demos, vae = root / "demos", root / "vae"
    assert main(["demos", ENV, "--episodes", "6", "--out", str(demos)]) == 0
    assert main(["pretrain", "--demos", str(demos), "--preset", "smoke", "--out", str(vae)]) == 0
    run = root / "digail"
    assert main(["train", "--demos", str(demos), "--vae", str(vae), "--preset", "smoke", "--out", str(run)]) == 0
    return root, demos, vae


def test_train_evaluate_compose_segment_smoke(smoke_runs, capsys):
    root, demos, vae = smoke_runs
    run = root / "digail"
    for name in ("model.pt", "checkpoint.pt", "config.json", "metrics.csv"):
        assert (run / name).exists(), name
    config = json.loads((run / "config.json").read_text())
    assert config["schema"] == 1 and config["kind"] == "digail" and config["train"]["iterations"] == 2
    assert config["demos"] == str(demos.resolve()) and config["vae_run"] == str(vae.resolve())  # cwd-independent
    _, meta = load_model(run / "model.pt")
    assert meta["config"] == config  # model.pt carries the run's config
    header = (run / "metrics.csv").read_text().splitlines()[0]
    for key in ("losses/policy", "disc/accuracy", "rollout/bonus", "perf/sps"):
        assert key in header
    assert main(["evaluate", str(run), "--episodes", "4"]) == 0
    ev = json.loads((run / "eval.json").read_text())
    assert ev["episodes"] == 4 and "order_correct_rate" in ev and "radius_error" in ev
    assert main(["compose", str(run), "--schedule", "1:60,0:60", "--episodes", "3"]) == 0
    comp = json.loads((run / "compose.json").read_text())
    assert "order_reversed_rate" in comp and (run / "figures" / "compose.png").exists()
    assert main(["compose", str(run), "--order", "1,0", "--episodes", "3"]) == 0
    comp = json.loads((run / "compose.json").read_text())
    assert comp["order"] == [1, 0] and len(comp["switch_steps"]) == 3 and "order_reversed_rate" in comp
    gail = root / "gail"
    assert main(["train", "--method", "gail", "--demos", str(demos), "--preset", "smoke", "--out", str(gail)]) == 0
    assert json.loads((gail / "config.json").read_text())["method"] == "gail"


@pytest.mark.parametrize("argv, phrase", [
    (["train", "--demos", "/nonexistent/demos", "--vae", "x"], "no Minari dataset"),
    (["compose", "/nonexistent/run", "--schedule", "1:60"], "does not exist"),
])
def test_bad_input_exits_2_with_one_line(argv, phrase, capsys):
    assert main(argv) == 2
    err = capsys.readouterr().err.strip()
    assert phrase in err and len(err.splitlines()) == 1


def test_digail_without_vae_and_bad_schedule_exit_2(smoke_runs, tmp_path, capsys):
    root, demos, vae = smoke_runs
    out = tmp_path / "nope"
    assert main(["train", "--demos", str(demos), "--preset", "smoke", "--out", str(out)]) == 2
    assert "--vae" in capsys.readouterr().err
    assert not out.exists()  # nothing half-written
    run = root / "digail"
    assert main(["compose", str(run), "--schedule", "7:10"]) == 2
    assert "codes" in capsys.readouterr().err
    assert main(["compose", str(run), "--schedule", "banana"]) == 2


def test_sigkill_then_resume_completes(smoke_runs, tmp_path):
    _, demos, vae = smoke_runs
    run = tmp_path / "killed"
    cmd = [sys.executable, "-m", "digail.cli", "train", "--demos", str(demos), "--vae", str(vae), "--preset", "smoke",
           "--train.iterations", "40", "--train.checkpoint-every", "2", "--out", str(run)]
    env = {**os.environ, "PYTHONUNBUFFERED": "1"}
    proc = subprocess.Popen(cmd, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, env=env,
                            start_new_session=True)
    ckpt = run / "checkpoint.pt"
    deadline = time.time() + 120
    while time.time() < deadline and proc.poll() is None:
        if ckpt.exists():
            state = torch.load(ckpt, weights_only=True)
            if state["iteration"] >= 4:
                break
        time.sleep(0.05)
    assert proc.poll() is None, "training finished before it could be killed; raise --train.iterations"
    os.killpg(proc.pid, signal.SIGKILL)
    proc.wait()
    killed_at = torch.load(ckpt, weights_only=True)["iteration"]
    assert 4 <= killed_at < 40
    done = subprocess.run([sys.executable, "-m", "digail.cli", "train", "--resume", str(run)], env=env,
                          capture_output=True, text=True, timeout=300)
    assert done.returncode == 0, done.stderr[-2000:]
    assert f"resuming {run} at iteration {killed_at}" in done.stdout
    final = torch.load(ckpt, weights_only=True)
    assert final["iteration"] == 40
    assert final["global_step"] == 40 * 64
    rows = (run / "metrics.csv").read_text().splitlines()
    iters = [float(r.split(",")[1]) for r in rows[1:]]
    assert iters[-1] == 40.0
    assert iters == sorted(set(iters)), "metrics.csv repeats iterations after the resume"


def test_resume_until_extends_a_finished_run(smoke_runs, tmp_path, capsys):
    import shutil

    root, demos, vae = smoke_runs
    run = tmp_path / "extended"
    shutil.copytree(root / "digail", run)
    assert main(["evaluate", str(run), "--episodes", "2"]) == 0
    before = (run / "eval.json").read_text()
    assert main(["train", "--resume", str(run), "--until", "4"]) == 0
    state = torch.load(run / "checkpoint.pt", weights_only=True)
    assert state["iteration"] == 4
    assert json.loads((run / "config.json").read_text())["train"]["iterations"] == 4
    assert not (run / "eval.json").exists() and (run / "eval.iteration-2.json").read_text() == before
    # two iterations more are the same as a run started with four
    fresh = tmp_path / "four"
    assert main(["train", "--demos", str(demos), "--vae", str(vae), "--preset", "smoke", "--train.iterations", "4",
                 "--out", str(fresh)]) == 0
    a, _ = load_model(run / "model.pt")
    b, _ = load_model(fresh / "model.pt")
    for (name, x), y in zip(a.state_dict().items(), b.state_dict().values(), strict=True):
        assert torch.equal(x, y), name
    capsys.readouterr()
    # the length it has: nothing to do; a shorter one, and --until without a run, are one sentence each
    config = (run / "config.json").read_text()
    assert main(["train", "--resume", str(run), "--until", "4"]) == 0
    assert (run / "config.json").read_text() == config and (run / "eval.iteration-2.json").exists()
    assert main(["train", "--resume", str(run), "--until", "3"]) == 2
    assert "done 4 iterations already" in capsys.readouterr().err
    assert (run / "config.json").read_text() == config
    assert main(["train", "--demos", str(demos), "--until", "3", "--out", str(tmp_path / "x")]) == 2
    assert "--resume" in capsys.readouterr().err and not (tmp_path / "x").exists()
