"""Failure-path probes of code named by data: no module runs because a dataset, a run folder or a sweep
spec names it; D's views of the user's own fail in one sentence; the messages that once said the wrong thing. The
planted modules check that they never ran. The probes, with what each gets, are the reliability page's section of
the same name (docs/reference/errors.md).
"""

from __future__ import annotations

import json
import os
import shutil
import signal
import subprocess
import sys
from collections.abc import Callable
from pathlib import Path

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq
import pytest
from probe_kit import (
    CW,
    CW_DEMOS,
    MW_DEMOS,
    RUN,
    Probe,
    ProbeTable,
    assert_published,
    check_probe,
    cli,
    mw_train,
    plant,
    ran,
    sweep_check,
)

from digail.cli import main
from digail.errors import UserError

PROBES = ProbeTable()
probe = PROBES.add


def _spec(env_id: str, entry: str) -> str:
    from gymnasium.envs.registration import EnvSpec

    return str(EnvSpec(id=env_id, entry_point=entry, max_episode_steps=20).to_json())


def _dataset_naming(tmp: Path, env_id: str, entry: str) -> Path:
    """A small Minari dataset (4 episodes of a 1-d walk) whose metadata names `env_id` made by `entry`."""
    from digail.data.minari_write import write_dataset
    from digail.data.trajectory import Trajectory

    trajs = [Trajectory(obs=np.linspace(0, 1, 21, dtype=np.float32)[:, None] + k,
                        acts=np.ones((20, 1), np.float32)) for k in range(4)]
    import gymnasium as gym

    space = gym.spaces.Box(-10.0, 10.0, (1,), np.float32)
    path = write_dataset(trajs, tmp / "ds", env_id=None, dataset_id="walk/expert-v0", observation_space=space,
                         action_space=gym.spaces.Box(-1.0, 1.0, (1,), np.float32))
    meta_file = path / "data" / "metadata.json"
    meta = json.loads(meta_file.read_text())
    meta["env_spec"] = _spec(env_id, entry)
    meta_file.write_text(json.dumps(meta))
    return path




# ------------------------------------------------------------------------------------------------ no code from data
@probe("data-dataset-entry-point", "`digail pretrain --demos ds` on a Minari dataset whose env_spec names "
       "`shuttle5a:Env`, with shuttle5a.py in the current folder", None)
def _dataset_entry(tmp: Path) -> None:
    plant(tmp, "shuttle5a", "import gymnasium as gym\ngym.register('Shuttle5a-v0', entry_point='shuttle5a:Env')\n")
    _dataset_naming(tmp, "Shuttle5a-v0", "shuttle5a:Env")
    cli(tmp, "pretrain", "--demos", "ds", "--codes", "2", "--preset", "smoke", "--vae.steps", "2",
        "--vae.init-steps", "0", "--out", "vae")


@probe("data-dataset-entry-point-train", "`digail train --demos ds` on the same dataset: the env it names is made "
       "only when its module is named", "pass --env shuttle5b:Shuttle5b-v0 to allow it")
def _dataset_entry_train(tmp: Path) -> None:
    plant(tmp, "shuttle5b", "import gymnasium as gym\ngym.register('Shuttle5b-v0', entry_point='shuttle5b:Env')\n")
    _dataset_naming(tmp, "Shuttle5b-v0", "shuttle5b:Env")
    cli(tmp, "train", "--demos", "ds", "--preset", "smoke", "--out", "run-new")


def _run_naming(tmp: Path, entry: str, env_id: str = "Shuttle5-v0") -> Path:
    import shutil

    run = tmp / "run"
    shutil.copytree(RUN, run)
    config = json.loads((run / "config.json").read_text())
    config["env_spec"] = _spec(env_id, entry)
    (run / "config.json").write_text(json.dumps(config))
    return run


@probe("data-run-folder-module", "`cd run && digail report .` where run/config.json's env_spec names "
       "`shipped5:Env` and run/shipped5.py exists", None)
def _run_module(tmp: Path) -> None:
    run = _run_naming(tmp, "shipped5:Env")
    plant(run, "shipped5")
    cli(run, "report", ".")


@probe("data-run-folder-evaluate", "`digail evaluate run` where run/config.json's env_spec names `shipped5e:Env` "
       "(an env id digail does not know) and shipped5e.py is in the current folder (the run's model.pt names "
       "Pendulum-v1, which it is evaluated in)", None)
def _run_evaluate(tmp: Path) -> None:
    run = _run_naming(tmp, "shipped5e:Env", "Shuttle5e-v0")
    config = json.loads((run / "config.json").read_text())
    config["env_id"] = "Shuttle5e-v0"
    (run / "config.json").write_text(json.dumps(config))
    plant(tmp, "shipped5e")
    cli(tmp, "evaluate", "run", "--episodes", "1")


def _resume_config(tmp: Path, view: str) -> None:
    (tmp / "run").mkdir()
    config = {"kind": "gail", "env_id": CW, "seed": 0, "train": {"disc_obs": view},
              "args": {"env": CW, "demos": CW_DEMOS, "seed": 0, "method": "gail", "preset": "smoke",
                       "train": {"disc_obs": view}}}
    (tmp / "run" / "config.json").write_text(json.dumps(config))


@probe("data-resume-disc-obs", "`digail train --resume run` where run/config.json's disc_obs names "
       "`view5a:view` and view5a.py is in the current folder", "--train.imitation.disc-obs view5a:view")
def _resume_view(tmp: Path) -> None:
    plant(tmp, "view5a", "def view(x):\n    return x\n")
    _resume_config(tmp, "view5a:view")
    cli(tmp, "train", "--resume", "run")


@probe("data-resume-other-disc-obs", "`digail train --resume run --train.imitation.disc-obs view5c:view` where "
       "config.json records `view5b:view`", "--train.imitation.disc-obs view5b:view")
def _resume_other_view(tmp: Path) -> None:
    plant(tmp, "view5b", "def view(x):\n    return x\n")
    plant(tmp, "view5c", "def view(x):\n    return x\n")
    _resume_config(tmp, "view5b:view")
    cli(tmp, "train", "--resume", "run", "--train.imitation.disc-obs", "view5c:view")


@probe("data-resume-env-module", "`digail train --resume run` where run/config.json's env id is "
       "`shipped5g:Shuttle5g-v0` (Gymnasium imports an id's module part) and shipped5g.py is in the current folder",
       "pass --env shipped5g:Shuttle5g-v0 to allow it")
def _resume_env_module(tmp: Path) -> None:
    plant(tmp, "shipped5g")
    (tmp / "run").mkdir()
    env = "shipped5g:Shuttle5g-v0"
    (tmp / "run" / "config.json").write_text(json.dumps({
        "kind": "gail", "env_id": env, "seed": 0,
        "args": {"env": env, "demos": CW_DEMOS, "seed": 0, "method": "gail", "preset": "smoke"}}))
    cli(tmp, "train", "--resume", "run")


@probe("data-report-env-module", "`digail report run` where run/config.json's env id is `shipped5h:Shuttle5h-v0` and "
       "shipped5h.py is in the current folder", None)
def _report_env_module(tmp: Path) -> None:
    run = _run_naming(tmp, "shipped5h:Env", "Shuttle5h-v0")
    config = json.loads((run / "config.json").read_text())
    config["env_id"] = "shipped5h:Shuttle5h-v0"
    (run / "config.json").write_text(json.dumps(config))
    plant(tmp, "shipped5h")
    cli(tmp, "report", "run")


def _in(tmp: Path, fn: Callable[[], object]) -> object:

    old = Path.cwd()
    os.chdir(tmp)
    try:
        return fn()
    finally:
        os.chdir(old)


for _pid, _value, _expect in [
    ("sweep-disc-obs-os-system", "os:system", "Python's standard library"),
    ("sweep-disc-obs-subprocess", "subprocess:getoutput", "Python's standard library"),
    ("sweep-disc-obs-builtins", "builtins:exec", "Python's standard library"),
    ("sweep-disc-obs-missing", "nowhere5:view", "cannot import module 'nowhere5'"),
]:
    probe(_pid, f"`digail sweep --set train.imitation.disc_obs={_value}`", _expect)(
        lambda tmp, v=_value: _in(tmp, lambda: sweep_check((f"train.imitation.disc_obs={v}",))))


@probe("sweep-env-module", "`digail sweep` whose spec's envs name `walk5s:Walk5s-v0` (the user's module, "
       "which registers the env) with demonstrations recorded in it", None)
def _sweep_env_module(tmp: Path) -> None:
    plant(tmp, "walk5s", "import gymnasium as gym\nimport numpy as np\n"
                         "class Env(gym.Env):\n"
                         "    observation_space = gym.spaces.Box(-10.0, 10.0, (1,), np.float32)\n"
                         "    action_space = gym.spaces.Box(-1.0, 1.0, (1,), np.float32)\n"
                         "gym.register('Walk5s-v0', entry_point='walk5s:Env', max_episode_steps=20)\n")
    _dataset_naming(tmp, "Walk5s-v0", "walk5s:Env")
    spec = '[[grid]]\nenvs = ["walk5s:Walk5s-v0"]\nmethods = ["gail"]\ndemos = "ds"\n'
    _in(tmp, lambda: sweep_check(spec=spec, tmp=tmp))


@probe("sweep-disc-obs-not-a-function", "`digail sweep --set train.imitation.disc_obs=view5d:THRESHOLD` (a number "
       "in the user's module)", "is not a function of yours")
def _sweep_number(tmp: Path) -> None:
    plant(tmp, "view5d", "THRESHOLD = 3\n")
    _in(tmp, lambda: sweep_check(("train.imitation.disc_obs=view5d:THRESHOLD",)))


@probe("sweep-disc-obs-two-arguments", "`digail sweep --set train.imitation.disc_obs=view5e:view` where view takes two "
       "arguments", "does not take one argument")
def _sweep_two(tmp: Path) -> None:
    plant(tmp, "view5e", "def view(x, y):\n    return x\n")
    _in(tmp, lambda: sweep_check(("train.imitation.disc_obs=view5e:view",)))


@probe("sweep-disc-obs-ok", "`digail sweep --set train.imitation.disc_obs=view5f:view` (a view of the user's)", None)
def _sweep_ok(tmp: Path) -> None:
    plant(tmp, "view5f", "def view(x):\n    return x[:, :1]\n")
    _in(tmp, lambda: sweep_check(("train.imitation.disc_obs=view5f:view",)))


# ------------------------------------------------------------------------------------------------ D's views
SMOKE = ["--method", "gail", "--demos", CW_DEMOS, "--preset", "smoke", "--train.iterations", "1"]

for _pid, _what, _body, _expect in [
    ("view-syntax-error", "a module with a syntax error", "def view(x)\n    return x\n", "has a syntax error"),
    ("view-raises-at-import", "a module that raises at import", "raise RuntimeError('no GPU here')\n",
     "raised RuntimeError: no GPU here"),
    ("view-exits-at-import", "a module that calls sys.exit() at import", "import sys\nsys.exit(3)\n",
     "raised SystemExit"),
    ("view-exits-when-called", "a view that calls sys.exit()", "import sys\ndef view(x):\n    sys.exit(0)\n",
     "fails on the demonstrations' observations (SystemExit"),
]:
    def _view_module(tmp: Path, name: str = _pid.replace("-", "_"), body: str = _body) -> None:
        plant(tmp, name, body)
        cli(tmp, "train", *SMOKE, "--train.imitation.disc-obs", f"{name}:view", "--out", "run-new")

    probe(_pid, f"`digail train --train.imitation.disc-obs m:view` with {_what}", _expect)(_view_module)

for _pid, _value, _expect in [
    ("view-relative-module", ".views:view", "not an absolute module name"),
    ("view-sys-exit", "sys:exit", "Python's standard library"),
    ("view-os-system", "os:system", "Python's standard library"),
]:
    probe(_pid, f"`digail train --train.imitation.disc-obs {_value}`", _expect)(
        lambda tmp, v=_value: cli(tmp, "train", *SMOKE, "--train.imitation.disc-obs", v, "--out", "run-new"))


@probe("view-nan-on-agent", "`digail train --train.imitation.disc-obs m:view` with a view that is finite on the "
       "demonstrations and NaN on everything after (the run folder it made must not stay without a checkpoint)",
       "gives NaN or infinite features on observations met during training")
def _view_nan_later(tmp: Path) -> None:
    plant(tmp, "view_nan5", "calls = [0]\ndef view(x):\n    calls[0] += 1\n"
                            "    return x if calls[0] == 1 else x * float('nan')\n")
    cli(tmp, "train", *SMOKE, "--train.imitation.disc-obs", "view_nan5:view", "--out", "run-new")


@probe("view-width-changes", "`digail train --train.imitation.disc-obs m:view` with a view that gives 2 features on "
       "the demonstrations and 1 after", "must give the same number of features for every observation")
def _view_width_later(tmp: Path) -> None:
    plant(tmp, "view_width5", "calls = [0]\ndef view(x):\n    calls[0] += 1\n"
                              "    return x if calls[0] == 1 else x[:, :1]\n")
    cli(tmp, "train", *SMOKE, "--train.imitation.disc-obs", "view_width5:view", "--out", "run-new")


# ------------------------------------------------------------------------------------------------ messages
@probe("msg-compose-episodes-huge", "`digail compose RUN --episodes 1000000000000`",
       "--episodes must be at most 1,000,000")
def _compose_huge(tmp: Path) -> None:
    import shutil

    shutil.copytree(RUN, tmp / "run")
    cli(tmp, "compose", "run", "--episodes", "1000000000000")


FORMATS = Path(__file__).resolve().parents[1] / "tests" / "data" / "formats"


@probe("msg-lerobot-1e300", "`digail import` a LeRobot dataset whose float64 `observation.state` holds 1e300 "
       "(finite, beyond float32)", "beyond float32's range")
def _lerobot_huge(tmp: Path) -> None:
    import shutil


    shutil.copytree(FORMATS / "lerobot", tmp / "lr")
    frames = tmp / "lr" / "data" / "chunk-000" / "file-000.parquet"
    table = pq.read_table(frames)
    rows = table.column("observation.state").to_pylist()
    rows[3] = [1e300] * len(rows[3])
    column = pa.array(rows, type=pa.list_(pa.float64(), len(rows[3])))
    table = table.set_column(table.schema.get_field_index("observation.state"), "observation.state", column)
    pq.write_table(table.replace_schema_metadata(None), frames)
    info = json.loads((tmp / "lr" / "meta" / "info.json").read_text())
    info["features"]["observation.state"]["dtype"] = "float64"
    (tmp / "lr" / "meta" / "info.json").write_text(json.dumps(info))
    cli(tmp, "import", "lr", "--out", "out")


# ------------------------------------------------------------------------------------------------ on Meta-World
for _pid, _value, _expect in [
    ("again-view-stdlib-shutil", "shutil:rmtree", "Python's standard library"),
    ("again-view-importlib", "importlib:import_module", "Python's standard library"),
    ("again-view-dotted-stdlib", "os.path:join", "Python's standard library"),
    ("again-view-fetch-on-metaworld", "digail.envs.fetch:relative_view", None),
    ("again-view-class", "collections:OrderedDict", "Python's standard library"),
    ("again-view-missing-function", "digail.envs.fetch:no_such_view", "has no 'no_such_view'"),
    ("again-view-trailing-colon", "mymod:", "all, relative or module:function"),
    ("again-view-two-colons", "a:b:c", "all, relative or module:function"),
]:
    probe(_pid, f"`digail train --demos {MW_DEMOS} --train.imitation.disc-obs {_value}`", _expect)(
        lambda tmp, v=_value: mw_train(tmp, "--train.imitation.disc-obs", v))


for _pid, _text, _expect in [
    ("again-spec-disc-obs-os", f'envs = ["{CW}"]\n[set]\n"train.imitation.disc_obs" = "os:system"\n',
     "standard library"),
    ("again-spec-grid-disc-obs",
     f'[[grid]]\nenvs = ["{CW}"]\nset = {{ "train.imitation.disc_obs" = ["all", "sys:exit"] }}\n',
     "standard library"),
]:
    probe(_pid, f"`digail sweep --spec spec.toml` whose spec sets {_text.split(chr(10))[-2]}", _expect)(
        lambda tmp, t=_text: sweep_check(spec=t, tmp=tmp))


@probe("again-mw-run-folder-module", "`digail report run` where a Meta-World run's config.json names env "
       "`evil6b:MW-v0` and evil6b.py is in the current folder", None)
def _mw_run_module(tmp: Path) -> None:
    shutil.copytree(RUN, tmp / "run")
    config = json.loads((tmp / "run" / "config.json").read_text())
    config["env_id"] = "evil6b:MW-v0"
    (tmp / "run" / "config.json").write_text(json.dumps(config))
    plant(tmp, "evil6b")
    cli(tmp, "report", "run")


@probe("again-resume-env-module", "`digail train --resume run` where config.json's env is `evil6c:MW-v0`",
       "pass --env evil6c:MW-v0 to allow it")
def _mw_resume(tmp: Path) -> None:
    plant(tmp, "evil6c")
    (tmp / "run").mkdir()
    (tmp / "run" / "config.json").write_text(json.dumps({
        "kind": "gail", "env_id": "evil6c:MW-v0", "seed": 0,
        "args": {"env": "evil6c:MW-v0", "demos": MW_DEMOS, "seed": 0, "method": "gail", "preset": "smoke"}}))
    cli(tmp, "train", "--resume", "run")




# ------------------------------------------------------------------------------------------------ Ctrl-C, NaN loss
def test_ctrl_c_while_the_command_still_imports_is_one_line(monkeypatch: pytest.MonkeyPatch,
                                                           capsys: pytest.CaptureFixture[str]) -> None:
    """Ctrl-C in the first seconds of `digail train --resume RUN` (torch still importing) ends it cleanly."""
    import digail.utils

    def interrupted(n: int) -> None:
        raise KeyboardInterrupt

    monkeypatch.setattr(digail.utils, "set_torch_threads", interrupted)
    assert main(["train", "--resume", "run"]) == 130
    err = capsys.readouterr().err
    assert err == "digail train: stopped by SIGINT before it began; nothing was written.\n", err


def test_ctrl_c_while_the_package_imports_is_one_line(tmp_path: Path) -> None:
    """The `digail` script interrupted while `import digail` runs (its first second): one line, status 130."""

    code = ("import builtins, os, signal, sys\n"
            "sys.argv[0] = '/usr/bin/digail'\n"
            "real = builtins.__import__\n"
            "def hook(name, *a, **k):\n"
            "    if name == 'gymnasium' and 'gymnasium' not in sys.modules:\n"
            "        os.kill(os.getpid(), signal.SIGINT)\n"
            "    return real(name, *a, **k)\n"
            "builtins.__import__ = hook\n"
            "import digail\n"
            "print('imported')\n")
    # the child starts with Ctrl-C at its default, as from a terminal: a test session run in the background (a
    # non-interactive shell's `cmd &`) ignores SIGINT, and an ignored SIGINT is inherited and stays ignored
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120, cwd=tmp_path,
                          preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL))
    assert done.returncode == 130 and "imported" not in done.stdout, (done.returncode, done.stderr[-2000:])
    assert done.stderr == "digail: stopped by SIGINT before it began; nothing was written.\n", done.stderr[-2000:]


def test_a_training_error_is_one_sentence(monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]) -> None:
    """Training that cannot go on (a NaN loss) ends with one sentence and status 1, not a traceback."""
    import digail.commands.evaluate
    from digail.errors import TrainingError

    def fails(args: object) -> None:
        raise TrainingError("non-finite loss (policy) at iteration 3; the last good checkpoint is kept - lower the "
                            "learning rate or check the demonstrations.")

    monkeypatch.setattr(digail.commands.evaluate, "evaluate_command", fails)
    assert main(["evaluate", "run"]) == 1
    err = capsys.readouterr().err.splitlines()
    assert len(err) == 1 and err[0].startswith("digail evaluate: error: non-finite loss"), err


def test_an_id_with_a_module_part_needs_the_module_named_or_imported(tmp_path: Path,
                                                                     monkeypatch: pytest.MonkeyPatch) -> None:
    """An env id `module:EnvId` from data reaches Gymnasium (whose `gym.make` would import the module) only when the
    command line named the module or it is imported already (a Python caller's own import): no new code runs."""
    import importlib

    from digail.user_envs import check_no_module

    monkeypatch.syspath_prepend(str(tmp_path))
    plant(tmp_path, "mine5p")
    plant(tmp_path, "other5p")
    with pytest.raises(UserError, match="pass --env other5p:Other-v0 to allow it"):
        check_no_module("other5p:Other-v0")
    importlib.import_module("mine5p")
    assert check_no_module("mine5p:Mine-v0") == "Mine-v0"
    assert check_no_module("Plain-v0") == "Plain-v0"
    assert ran(tmp_path) == ["mine5p.ran"]


# ------------------------------------------------------------------------------------------------ the probes
@pytest.mark.parametrize("p", PROBES, ids=[p.id for p in PROBES])
def test_probe(p: Probe, tmp_path: Path, request: pytest.FixtureRequest) -> None:
    check_probe(p, tmp_path, request.getfixturevalue("base") if p.on_base else None)


def test_the_reliability_page_lists_every_probe() -> None:
    assert_published(PROBES, "Probes: code named by data")
