"""RL experts: export/load round trip, training with resume, bad input, shipped experts and datasets."""

from __future__ import annotations

import dataclasses
import json
import os
import pickle
import tempfile
from pathlib import Path

import gymnasium as gym
import numpy as np
import pytest
import torch

import digail  # noqa: F401  (registers the envs)
from digail.checkpoint import run_config
from digail.cli import main
from digail.commands.expert import ExpertArgs, expert_command
from digail.errors import UserError
from digail.experts.recipes import RECIPES
from digail.experts.rl import (
    ExpertSpec,
    build_sb3_model,
    evaluate_expert,
    export_expert,
    load_expert,
    load_expert_actor,
    rl_expert_envs,
    shipped_expert_path,
    spec_for,
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


PPO_GSDE = ExpertSpec(
    steps=200_000, target=-200.0, n_envs=4, gamma=0.9, use_sde=True, norm_reward=False,
    ppo={"n_steps": 1024, "batch_size": 64, "n_epochs": 10, "learning_rate": ("linear", 1e-3), "gae_lambda": 0.95,
         "clip_range": 0.2, "ent_coef": 0.0, "sde_sample_freq": 4},
    checkpoint_every=20_000, eval_every=10_000, eval_episodes=20)
"""the PPO + gSDE recipe Pendulum's expert was trained with before SAC (exercises the PPO path on Pendulum)"""

PPO_REFERENCE = Path(__file__).parent / "data" / "ppo_expert_reference.json"
"""actions of the shipped PPO experts recorded before the SAC export was added"""


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
    model, venv = build_sb3_model("Pendulum-v1", spec_for("Pendulum-v1"), seed=0, device="cpu")
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
@pytest.mark.parametrize("recipe", ["gsde", "Hopper-v5"])  # gSDE policy / plain Gaussian policy
def test_exported_actor_matches_sb3_deterministic_actions(tmp_path: Path, recipe: str) -> None:
    """The pickle-free export reproduces SB3's own deterministic prediction, normalisation included."""
    torch.manual_seed(0)
    spec = PPO_GSDE if recipe == "gsde" else spec_for(recipe)
    model, venv = build_sb3_model("Pendulum-v1", spec, seed=0, device="cpu")
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


def test_exported_sac_actor_matches_sb3_deterministic_actions(tmp_path: Path) -> None:
    """SAC's export (tanh-squashed mean rescaled to the box, raw observations) reproduces SB3's prediction."""
    torch.manual_seed(0)
    spec = spec_for("Pendulum-v1")
    assert spec.algo == "sac"
    model, venv = build_sb3_model("Pendulum-v1", spec, seed=0, device="cpu")
    with torch.no_grad():  # large pre-activations: actions near the bounds as well as inside them
        for p in model.policy.actor.mu.parameters():
            p.mul_(10.0)
    export_expert(model, venv, "Pendulum-v1", tmp_path / "e.pt", {"steps": 0})
    payload = torch.load(tmp_path / "e.pt", weights_only=True)
    assert payload["algo"] == "sac" and payload["squash"] is True
    actor, meta = load_expert_actor("Pendulum-v1", tmp_path / "e.pt")
    assert actor.squash and meta["algo"] == "sac"
    policy = load_expert("Pendulum-v1", tmp_path / "e.pt")
    rng = np.random.default_rng(0)
    obs = np.concatenate([rng.normal(scale=3.0, size=(62, 3)), [[0, 0, 1e4], [0, 0, -1e4]]]).astype(np.float32)
    expected, _ = model.predict(obs, deterministic=True)
    actions = policy(obs)
    np.testing.assert_allclose(actions, expected, atol=1e-5)
    assert (np.abs(actions) <= 2.0).all() and (np.abs(actions) > 1.9).any() and (np.abs(actions) < 1.0).any()


def test_ppo_experts_act_as_before_sac_export() -> None:
    """The PPO experts shipped before SAC (format digail-expert-v1, no "squash" key) act as they did."""
    reference = json.loads(PPO_REFERENCE.read_text())["experts"]
    assert set(reference) == {"InvertedPendulum-v5", "Hopper-v5", "Walker2d-v5"}
    for env_id, ref in reference.items():
        payload = torch.load(shipped_expert_path(env_id), weights_only=True)
        assert payload["algo"] == "ppo" and "squash" not in payload
        actor, _ = load_expert_actor(env_id)
        assert not actor.squash
        actions = load_expert(env_id)(np.asarray(ref["obs"], dtype=np.float32))
        # Exact up to float32 rounding: CPUs of another make (AMD against Intel) differ in the last bit of a
        # matrix product, while any change of weights, normalisation or squashing moves actions by far more.
        np.testing.assert_allclose(actions, np.asarray(ref["actions"], dtype=np.float32), rtol=1e-6, atol=1e-6)


@pytest.mark.parametrize("algo", ["ppo", "sac"])
def test_training_checkpoints_resumes_and_evaluates(tmp_path: Path, monkeypatch: pytest.MonkeyPatch,
                                                    algo: str) -> None:
    """A short run, then --resume for as much again: steps carry over and eval.json holds 50 episodes."""
    out = tmp_path / "pendulum"
    pendulum = RECIPES["Pendulum-v1"]
    assert pendulum.algo == "sac"
    if algo == "ppo":  # one PPO rollout per run
        recipe = PPO_GSDE
        rollout = PPO_GSDE.n_envs * PPO_GSDE.ppo["n_steps"]
    else:  # SAC: past learning_starts, so gradient steps run before the first checkpoint
        recipe = dataclasses.replace(pendulum, eval_every=150, eval_episodes=2)
        rollout = 200
    monkeypatch.setitem(RECIPES, "Pendulum-v1", recipe)
    expert_command(ExpertArgs(env="Pendulum-v1", out=out, steps=rollout))
    assert (out / "checkpoints" / f"step_{rollout}.pt").is_file()
    first = json.loads((out / "eval.json").read_text())
    assert first["episodes"] == 50 and len(first["returns"]) == 50 and first["total_steps"] == rollout
    with pytest.raises(UserError, match="--resume"):
        expert_command(ExpertArgs(env="Pendulum-v1", out=out, steps=rollout))
    with pytest.raises(UserError, match="holds an expert for 'Pendulum-v1'"):
        expert_command(ExpertArgs(env="InvertedPendulum-v5", out=out, resume=True))
    expert_command(ExpertArgs(env="Pendulum-v1", out=out, steps=2 * rollout, resume=True))
    second = json.loads((out / "eval.json").read_text())
    assert second["total_steps"] == 2 * rollout
    config = json.loads((out / "config.json").read_text())  # the schema of every run folder
    assert set(run_config(kind="expert", env_id=None, demos=None, seed=0)) <= set(config)
    assert (config["kind"], config["env_id"], config["steps"]) == ("expert", "Pendulum-v1", 2 * rollout)
    assert config["expert"]["algo"] == recipe.algo and config["args"]["resume"] is True
    assert (out / "checkpoints" / f"step_{2 * rollout}.pt").is_file()
    if algo == "sac":
        assert (out / "checkpoints" / f"step_{2 * rollout}.replay.npz").is_file()
        assert json.loads((out / "progress.json").read_text())["evals"][0]["steps"] == 150
    # the evaluation is reproducible: the same expert and seeds give the same returns
    again = evaluate_expert("Pendulum-v1", load_expert("Pendulum-v1", out / "best_expert.pt"), 50, 10_000)
    np.testing.assert_allclose(again["returns"], second["returns"])


# ------------------------------------------------------------------------------------------ shipped files
@pytest.mark.parametrize("env_id", [pytest.param(e, marks=_maybe_mujoco(e)) for e in rl_expert_envs()])
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


def test_shipped_pendulum_expert_is_a_bounded_sac_actor() -> None:
    payload = torch.load(shipped_expert_path("Pendulum-v1"), weights_only=True)
    assert payload["algo"] == "sac" and payload["squash"] is True
    actor, meta = load_expert_actor("Pendulum-v1")
    assert actor.squash and meta["algo"] == "sac"
    policy = load_expert("Pendulum-v1")
    rng = np.random.default_rng(0)
    obs = np.concatenate([rng.normal(scale=[1.0, 1.0, 8.0], size=(256, 3)),
                          [[1, 0, 1e6], [-1, 0, -1e6]]]).astype(np.float32)
    actions = policy(obs)
    assert actions.shape == (258, 1) and np.isfinite(actions).all()
    assert (np.abs(actions) <= 2.0).all()


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


# ------------------------------------------------------------------------------------ pickle-free checkpoints
MARKER = Path(tempfile.gettempdir()) / "digail-expert-pickle-ran"


class _Hostile:
    def __reduce__(self):  # noqa: ANN204  (creates MARKER when unpickled)
        return os.system, (f"touch {MARKER}",)


@pytest.mark.parametrize("algo", ["ppo", "sac"])
def test_training_checkpoint_round_trip_is_exact(tmp_path: Path, algo: str) -> None:
    """A checkpoint written without pickle gives a freshly built model the same weights, optimiser state,
    normaliser statistics, replay buffer and counters."""
    from digail.experts.sb3 import load_checkpoint, save_checkpoint

    spec = PPO_GSDE if algo == "ppo" else spec_for("Pendulum-v1")
    model, venv = build_sb3_model("Pendulum-v1", spec, seed=0, device="cpu")
    rng = np.random.default_rng(1)
    with torch.no_grad():
        for p in model.policy.parameters():
            p.add_(torch.as_tensor(rng.normal(size=tuple(p.shape)), dtype=p.dtype))
    if algo == "ppo":
        venv.obs_rms.mean, venv.obs_rms.var, venv.obs_rms.count = rng.normal(size=3), rng.uniform(1, 2, 3), 77.0
    else:
        buf = model.replay_buffer
        for _ in range(5):
            obs = rng.normal(size=(1, 3)).astype(np.float32)
            buf.add(obs, obs + 1, rng.uniform(-2, 2, (1, 1)).astype(np.float32), np.ones(1, np.float32),
                    np.zeros(1, bool), [{}])
        with torch.no_grad():
            model.log_ent_coef.fill_(-0.7)
    model.num_timesteps, model._n_updates = 1234, 56
    save_checkpoint(model, venv, tmp_path / "step_1234")
    fresh, fresh_venv = build_sb3_model("Pendulum-v1", spec, seed=1, device="cpu")
    load_checkpoint(fresh, fresh_venv, tmp_path / "step_1234.pt", "cpu")
    for name, state in model.get_parameters().items():
        got = fresh.get_parameters()[name]
        if "optimizer" in name:
            assert got["param_groups"] == state["param_groups"]
            continue
        assert state.keys() == got.keys()
        for k in state:
            torch.testing.assert_close(got[k], state[k], rtol=0, atol=0)
    assert (fresh.num_timesteps, fresh._n_updates) == (1234, 56)
    if algo == "ppo":
        np.testing.assert_array_equal(fresh_venv.obs_rms.mean, venv.obs_rms.mean)
        np.testing.assert_array_equal(fresh_venv.obs_rms.var, venv.obs_rms.var)
        assert fresh_venv.obs_rms.count == 77.0
    else:
        assert (fresh.replay_buffer.pos, fresh.replay_buffer.full) == (5, False)
        np.testing.assert_array_equal(fresh.replay_buffer.observations[:5], model.replay_buffer.observations[:5])
        np.testing.assert_array_equal(fresh.replay_buffer.actions[:5], model.replay_buffer.actions[:5])
        assert fresh.log_ent_coef.item() == pytest.approx(-0.7)


def _plant(out: Path, kind: str) -> None:
    """An expert folder whose checkpoint files hold a pickle that would run code."""
    from digail.experts.sb3 import save_checkpoint

    ckpt = out / "checkpoints"
    ckpt.mkdir(parents=True)
    (out / "progress.json").write_text(json.dumps({"env_id": "Pendulum-v1", "evals": []}))
    hostile = pickle.dumps(_Hostile())
    if kind == "checkpoint":
        (ckpt / "step_100.pt").write_bytes(hostile)
        return
    model, venv = build_sb3_model("Pendulum-v1", spec_for("Pendulum-v1"), seed=0, device="cpu")
    if kind == "replay buffer":  # a genuine checkpoint beside an .npz whose array unpickles
        save_checkpoint(model, venv, ckpt / "step_100")
        np.savez(ckpt / "step_100.replay.npz", observations=np.array([_Hostile()], dtype=object))
    else:  # the format earlier versions wrote: SB3's zip and a pickled replay buffer
        model.save(str(ckpt / "step_100.zip"))
        (ckpt / "step_100.replay.pkl").write_bytes(hostile)


@pytest.mark.parametrize("kind", ["checkpoint", "replay buffer", "old format"])
def test_expert_resume_runs_no_pickle(tmp_path: Path, capsys: pytest.CaptureFixture[str], kind: str) -> None:
    """`digail expert --resume` on a folder whose checkpoint files would run code when unpickled: nothing runs,
    one sentence, exit status 2."""
    out = tmp_path / "expert"
    _plant(out, kind)
    MARKER.unlink(missing_ok=True)
    capsys.readouterr()
    assert main(["expert", "Pendulum-v1", "--out", str(out), "--resume", "--steps", "2000"]) == 2
    err = capsys.readouterr().err.strip()
    assert not MARKER.exists(), "a pickle in the checkpoint folder ran"
    assert len(err.splitlines()) == 1 and "Traceback" not in err, err
    assert {"checkpoint": "corrupt", "replay buffer": "not plain arrays", "old format": "older"}[kind] in err, err
    assert not (out / "config.json").exists() and not (out / "wall_before_resume.txt").exists()


def test_expert_resume_past_a_damaged_progress_file(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """A cut-short progress.json (the evaluation history) does not stop a resume: the checkpoints carry the
    training; one warning says what was lost."""
    out = tmp_path / "expert"
    assert main(["expert", "Pendulum-v1", "--out", str(out), "--steps", "64"]) == 0
    (out / "progress.json").write_text('{"env_id": "Pend')
    capsys.readouterr()
    assert main(["expert", "Pendulum-v1", "--out", str(out), "--steps", "128", "--resume"]) == 0
    err = capsys.readouterr().err
    assert err.count("progress.json is damaged") == 1 and "Traceback" not in err
    assert json.loads((out / "progress.json").read_text())["env_id"] == "Pendulum-v1"  # rewritten whole
