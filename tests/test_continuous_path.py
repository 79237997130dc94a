"""The whole continuous-control path of Table 1 on the smoke preset: expert demonstrations -> pre-train -> GAIL and
Directed-Info GAIL -> evaluate, on Hopper-v5 (MuJoCo) and Pendulum-v1, exactly as a user types it."""

from __future__ import annotations

import json

import numpy as np
import pytest

from digail.checkpoint import load_model
from digail.cli import main

pytestmark = pytest.mark.mujoco


@pytest.mark.parametrize("env_id, episode_steps", [("Hopper-v5", None), ("Pendulum-v1", 200)])
def test_demos_pretrain_gail_digail_evaluate(env_id, episode_steps, tmp_path):
    demos, vae = tmp_path / "demos", tmp_path / "vae"
    assert main(["demos", env_id, "--episodes", "2", "--out", str(demos)]) == 0
    assert main(["pretrain", "--demos", str(demos), "--preset", "smoke", "--out", str(vae)]) == 0
    runs = {"gail": ["--method", "gail"], "digail": ["--method", "digail", "--vae", str(vae)]}
    for name, flags in runs.items():
        run = tmp_path / name
        assert main(["train", *flags, "--demos", str(demos), "--preset", "smoke", "--out", str(run)]) == 0
        assert main(["evaluate", str(run), "--episodes", "2"]) == 0
        ev = json.loads((run / "eval.json").read_text())
        assert ev["episodes"] == 2 and np.isfinite(ev["mean_return"])
        # the normalised return divides by the shipped expert's, measured the same way
        assert ev["expert"]["mean_return"] > 0 if env_id == "Hopper-v5" else ev["expert"]["mean_return"] < 0
        assert np.isfinite(ev["normalized_return"])
        if episode_steps is not None:  # Pendulum never terminates early: every episode is the time limit
            assert ev["mean_length"] == episode_steps
        model, meta = load_model(run / "model.pt")
        assert meta["config"]["method"] == name and meta["config"]["env_id"] == env_id
        assert model.codes == (1 if name == "gail" else 2)
        assert model.action.dim == (3 if env_id == "Hopper-v5" else 1)
