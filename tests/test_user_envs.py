"""Envs defined outside digail, in a fresh `digail` process each time (nothing registered in this one counts):
named as `module:EnvId` on the command line, also in the env worker processes and when a run folder is evaluated
later; the entry point a dataset or run folder records is used only when its module is named."""

from __future__ import annotations

import json
import os
import subprocess
import sys
import textwrap
from pathlib import Path

import numpy as np
import pytest

ENV_MODULE = textwrap.dedent('''
    import gymnasium as gym
    import numpy as np


    class Walk(gym.Env):
        observation_space = gym.spaces.Box(-5.0, 5.0, shape=(1,), dtype=np.float32)
        action_space = gym.spaces.Box(-1.0, 1.0, shape=(1,), dtype=np.float32)

        def reset(self, *, seed=None, options=None):
            super().reset(seed=seed)
            self.x = 0.0
            return np.array([self.x], np.float32), {}

        def step(self, action):
            self.x = float(np.clip(self.x + 0.1 * float(action[0]), -5.0, 5.0))
            return np.array([self.x], np.float32), -abs(self.x - 1.0), False, False, {}


    gym.register("LineWalk-v0", entry_point="line_walk:Walk", max_episode_steps=20)
''')
SMALL = ["--train.iterations", "1", "--train.ppo.num-envs", "2", "--train.ppo.batch-size", "32",
         "--train.ppo.minibatch-size", "16", "--train.ppo.epochs", "1"]


@pytest.fixture
def folder(tmp_path: Path) -> Path:
    """A folder holding the env's module and a dataset recorded in it (written in a child process, so that this
    one never registers the env)."""
    (tmp_path / "line_walk.py").write_text(ENV_MODULE)
    script = textwrap.dedent('''
        import numpy as np
        import line_walk
        from digail.data.minari_write import write_dataset
        from digail.data.trajectory import Trajectory
        trajs = []
        for _ in range(4):
            x, obs = 0.0, [[0.0]]
            for _ in range(20):
                x = min(x + 0.1, 5.0)
                obs.append([x])
            trajs.append(Trajectory(obs=np.array(obs, np.float32), acts=np.ones((20, 1), np.float32)))
        write_dataset(trajs, "demos", env_id="LineWalk-v0", dataset_id="linewalk/expert-v0")
    ''')
    subprocess.run([sys.executable, "-c", script], cwd=tmp_path, check=True, env=_env(), capture_output=True)
    return tmp_path


def _env() -> dict[str, str]:
    # the child finds digail as this process does, but not the env's module except through its current folder
    path = [p for p in sys.path if p and Path(p).resolve() != Path.cwd().resolve()]
    return {**os.environ, "PYTHONPATH": os.pathsep.join(path), "MUJOCO_GL": os.environ.get("MUJOCO_GL", "egl")}


def _digail(folder: Path, *args: str) -> subprocess.CompletedProcess[str]:
    # through `digail.cli.main` from a script, as the console script runs it: the current folder is not on sys.path
    code = "import sys; sys.path.remove(sys.path[0]) if sys.path[0] in ('', '.') else None; " \
           "from digail.cli import main; sys.exit(main(sys.argv[1:]))"
    return subprocess.run([sys.executable, "-c", code, *args], cwd=folder, env=_env(), capture_output=True,
                          text=True, timeout=300)


def test_env_named_with_its_module_and_through_the_dataset(folder: Path) -> None:
    r = _digail(folder, "pretrain", "--demos", "demos", "--codes", "2", "--preset", "smoke", "--out", "vae")
    assert r.returncode == 0, r.stderr  # the data alone: nothing imported
    # the id alone: the dataset's entry point names line_walk, a module no one named on the command line
    r = _digail(folder, "train", "--demos", "demos", "--vae", "vae", "--preset", "smoke", *SMALL, "--out", "run0")
    assert r.returncode == 2 and "pass --env line_walk:LineWalk-v0 to allow it" in r.stderr, r.stderr
    assert not (folder / "run0").exists()
    # module:EnvId: the module is imported, in this process and in the env workers, and the env is known by its id
    r = _digail(folder, "train", "--env", "line_walk:LineWalk-v0", "--demos", "demos", "--vae", "vae", "--preset",
                "smoke", "--train.backend", "subproc", *SMALL, "--out", "run1")
    assert r.returncode == 0, r.stderr
    config = json.loads((folder / "run1" / "config.json").read_text())
    assert config["env_id"] == "LineWalk-v0" and "line_walk:Walk" in config["env_spec"]
    r = _digail(folder, "train", "--env", "line_walk:LineWalk-v0", "--demos", "demos", "--vae", "vae", "--preset",
                "smoke", "--train.backend", "sync", *SMALL, "--out", "run2")
    assert r.returncode == 0, r.stderr
    assert json.loads((folder / "run2" / "config.json").read_text())["env_id"] == "LineWalk-v0"
    # a later command on the run folder: the env's module is named again (the folder's record is not enough)
    r = _digail(folder, "evaluate", "run1", "--episodes", "2")
    assert r.returncode == 2 and "--env line_walk:LineWalk-v0" in r.stderr, r.stderr
    r = _digail(folder, "evaluate", "run1", "--episodes", "2", "--env", "line_walk:LineWalk-v0")
    assert r.returncode == 0, r.stderr
    result = json.loads((folder / "run1" / "eval.json").read_text())
    assert result["episodes"] == 2 and np.isfinite(result["mean_return"])


def test_module_that_cannot_be_imported(folder: Path) -> None:
    r = _digail(folder, "train", "--env", "no_such_module:LineWalk-v0", "--demos", "demos", "--out", "run")
    assert r.returncode == 2 and not (folder / "run").exists()
    assert "cannot import module 'no_such_module'" in r.stderr and "PYTHONPATH" in r.stderr
    r = _digail(folder, "train", "--env", "line_walk:", "--demos", "demos", "--out", "run")
    assert r.returncode == 2 and "module:EnvId" in r.stderr


def test_dataset_of_an_env_whose_module_is_missing(folder: Path) -> None:
    (folder / "line_walk.py").unlink()
    r = _digail(folder, "pretrain", "--demos", "demos", "--codes", "2", "--preset", "smoke", "--out", "vae")
    assert r.returncode == 0, r.stderr  # pre-training needs the data only
    r = _digail(folder, "train", "--demos", "demos", "--vae", "vae", "--preset", "smoke", *SMALL, "--out", "run")
    assert r.returncode == 2 and "LineWalk-v0" in r.stderr and "cannot be made here" in r.stderr
