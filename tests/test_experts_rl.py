"""RL experts: export/load round trip, training with resume, bad input, shipped experts and datasets."""

from __future__ import annotations

import json
from pathlib import Path

import gymnasium as gym
import numpy as np
import pytest
import torch

import digail  # noqa: F401  (registers the envs)
from digail.cli import main
from digail.commands.expert import ExpertArgs, expert_command
from digail.errors import UserError
from digail.experts.rl import (
    EXPERT_SPECS,
    build_sb3_model,
    evaluate_expert,
    export_expert,
    load_expert,
    shipped_expert_path,
)

MUJOCO_ENVS = {"InvertedPendulum-v5", "Hopper-v5", "Walker2d-v5"}
SANITY_RETURN = {"Pendulum-v1": -400.0, "InvertedPendulum-v5": 1000.0, "Hopper-v5": 2000.0,
                 "Walker2d-v5": 2500.0}
"""mean over 3 episodes a working shipped expert clears easily (random play: about -1200, 5, 20, 0)"""

SHIPPED_DATASETS = {
    "digail/pendulum/expert-v0": ("Pendulum-v1", 25),
    "digail/invertedpendulum/expert-v0": ("InvertedPendulum-v5", 25),
    "digail/hopper/expert-v0": ("Hopper-v5", 50),
    "digail/walker2d/expert-v0": ("Walker2d-v5", 50),
    "digail/fetchpickandplace/expert-v0": ("digail/FetchPickAndPlace-v4", 500),
}


def _maybe_mujoco(env_id: str) -> list[pytest.MarkDecorator]:
    return [pytest.mark.mujoco] if env_id in MUJOCO_ENVS or "Fetch" in env_id else []


# ------------------------------------------------------------------------------------------- bad input
def test_unsupported_env_is_one_sentence_and_exit_status_2(capsys: pytest.CaptureFixture[str]) -> None:
    with pytest.raises(UserError, match="supported envs are Pendulum-v1"):
        expert_command(ExpertArgs(env="CartPole-v1"))
    assert main(["expert", "CartPole-v1"]) == 2
    err = capsys.readouterr().err.strip()
    assert err.count("\n") == 0 and "CartPole-v1" in err


def test_expert_file_for_another_env_or_not_an_expert_is_refused(tmp_path: Path) -> None:
    path = tmp_path / "pendulum.pt"
    model, venv = build_sb3_model("Pendulum-v1", EXPERT_SPECS["Pendulum-v1"], seed=0, device="cpu")
    export_expert(model, venv, "Pendulum-v1", path, {"steps": 0})
    with pytest.raises(UserError, match="trained for 'Pendulum-v1', not 'Hopper-v5'"):
        load_expert("Hopper-v5", path)
    junk = tmp_path / "junk.pt"
    junk.write_bytes(b"not a checkpoint")
    with pytest.raises(UserError, match="not a digail expert file"):
        load_expert("Pendulum-v1", junk)
    with pytest.raises(UserError, match="does not exist"):
        load_expert("Pendulum-v1", tmp_path / "missing.pt")
    # through the CLI: exit status 2, no dataset written (an expert labelled for Hopper, demos of Pendulum)
    hopper = tmp_path / "hopper.pt"
    export_expert(model, venv, "Hopper-v5", hopper, {"steps": 0})
    out = tmp_path / "demos"
    assert main(["demos", "Pendulum-v1", "--episodes", "1", "--out", str(out), "--expert", str(hopper)]) == 2
    assert not out.exists()


def test_resume_without_checkpoints_is_refused(tmp_path: Path) -> None:
    with pytest.raises(UserError, match="nothing to resume"):
        expert_command(ExpertArgs(env="Pendulum-v1", out=tmp_path / "x", resume=True))


# ------------------------------------------------------------------------------------- export / training
@pytest.mark.parametrize("recipe", ["Pendulum-v1", "Hopper-v5"])  # gSDE policy / plain Gaussian policy
def test_exported_actor_matches_sb3_deterministic_actions(tmp_path: Path, recipe: str) -> None:
    """The pickle-free export reproduces SB3's own deterministic prediction, normalisation included."""
    torch.manual_seed(0)
    model, venv = build_sb3_model("Pendulum-v1", EXPERT_SPECS[recipe], seed=0, device="cpu")
    rng = np.random.default_rng(0)
    venv.obs_rms.mean = rng.normal(size=3)
    venv.obs_rms.var = rng.uniform(0.1, 4.0, size=3)
    with torch.no_grad():  # make the untrained net's outputs large enough to exercise the action clipping
        for p in model.policy.action_net.parameters():
            p.mul_(2000.0)
    export_expert(model, venv, "Pendulum-v1", tmp_path / "e.pt", {"steps": 0})
    policy = load_expert("Pendulum-v1", tmp_path / "e.pt")
    obs = rng.normal(scale=3.0, size=(64, 3)).astype(np.float32)
    expected, _ = model.predict(venv.normalize_obs(obs), deterministic=True)
    actions = policy(obs)
    assert actions.shape == (64, 1)
    np.testing.assert_allclose(actions, expected, atol=1e-5)
    assert (np.abs(actions) == 2.0).any() and (np.abs(actions) < 2.0).any()  # some clipped, some not
    assert policy(obs[0]).shape == (1,)


def test_training_checkpoints_resumes_and_evaluates(tmp_path: Path) -> None:
    """One PPO rollout, then --resume for a second: steps carry over and eval.json holds 50 episodes."""
    out = tmp_path / "pendulum"
    rollout = EXPERT_SPECS["Pendulum-v1"].n_envs * EXPERT_SPECS["Pendulum-v1"].ppo["n_steps"]
    expert_command(ExpertArgs(env="Pendulum-v1", out=out, steps=rollout))
    assert (out / "checkpoints" / f"step_{rollout}.zip").is_file()
    first = json.loads((out / "eval.json").read_text())
    assert first["episodes"] == 50 and len(first["returns"]) == 50 and first["total_steps"] == rollout
    with pytest.raises(UserError, match="--resume"):
        expert_command(ExpertArgs(env="Pendulum-v1", out=out, steps=rollout))
    with pytest.raises(UserError, match="holds an expert for 'Pendulum-v1'"):
        expert_command(ExpertArgs(env="InvertedPendulum-v5", out=out, resume=True))
    expert_command(ExpertArgs(env="Pendulum-v1", out=out, steps=2 * rollout, resume=True))
    second = json.loads((out / "eval.json").read_text())
    assert second["total_steps"] == 2 * rollout
    assert (out / "checkpoints" / f"step_{2 * rollout}.zip").is_file()
    # the evaluation is reproducible: the same expert and seeds give the same returns
    again = evaluate_expert("Pendulum-v1", load_expert("Pendulum-v1", out / "best_expert.pt"), 50, 10_000)
    np.testing.assert_allclose(again["returns"], second["returns"])


# ------------------------------------------------------------------------------------------ shipped files
@pytest.mark.parametrize("env_id", [pytest.param(e, marks=_maybe_mujoco(e)) for e in EXPERT_SPECS])
def test_shipped_expert_loads_and_runs(env_id: str) -> None:
    if not shipped_expert_path(env_id).is_file():
        pytest.skip(f"no expert shipped for {env_id} yet")
    policy = load_expert(env_id)
    env = gym.make(env_id)
    obs, _ = env.reset(seed=0)
    batch = policy(np.stack([obs, obs]).astype(np.float32))
    assert batch.shape == (2, *env.action_space.shape)
    assert env.action_space.contains(batch[0].astype(env.action_space.dtype))
    result = evaluate_expert(env_id, policy, episodes=3, seed=10_000)
    assert result["mean"] >= SANITY_RETURN[env_id], result


@pytest.mark.parametrize("dataset_id", [pytest.param(d, marks=_maybe_mujoco(env)) for d, (env, _)
                                        in SHIPPED_DATASETS.items()])
def test_shipped_dataset_validates_against_its_env(dataset_id: str) -> None:
    from digail.data.minari_io import SHIPPED_ROOT, load_dataset
    from digail.data.validation import check_matches_env

    if not (SHIPPED_ROOT / dataset_id).is_dir():
        pytest.skip(f"{dataset_id} is not shipped yet")
    env_id, episodes = SHIPPED_DATASETS[dataset_id]
    if "Fetch" in env_id:
        pytest.importorskip("gymnasium_robotics")
    ds = load_dataset(dataset_id)
    assert ds.env_id == env_id and len(ds.trajs) == episodes
    check_matches_env(ds, env_id)
    manifest = json.loads((SHIPPED_ROOT / "MANIFEST.json").read_text())
    entry = next(e for e in manifest["datasets"] if e["id"] == dataset_id)
    assert entry["episodes"] == episodes and "expert_eval" in entry
    if "Fetch" in env_id:
        assert ds.has_labels
        for t in ds.trajs:
            assert set(np.diff(t.subtasks).tolist()) <= {0, 1} and t.subtasks[0] == 0


def test_dataset_for_another_env_is_refused() -> None:
    from digail.data.minari_io import SHIPPED_ROOT, load_dataset
    from digail.data.validation import check_matches_env

    if not (SHIPPED_ROOT / "digail/pendulum/expert-v0").is_dir():
        pytest.skip("the Pendulum dataset is not shipped yet")
    ds = load_dataset("digail/pendulum/expert-v0")
    with pytest.raises(UserError, match="has observations of shape"):
        check_matches_env(ds, "digail/CircleWorld-v0")
