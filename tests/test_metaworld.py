"""Meta-World tasks: the env (random placements, success, no raise past Meta-World's limit), the phase tracer that
labels the scripted experts' phases, and the shipped Meta-World demonstrations."""

from __future__ import annotations

import subprocess
import sys

import numpy as np
import pytest

import digail  # noqa: F401  (registers the envs)
from digail.envs.metaworld import EPISODE_STEPS, MIN_SEGMENT, PhaseTracer, env_id, merge_short_runs

SHIPPED_TASKS = ("pick-place", "assembly", "stick-pull", "shelf-place", "basketball", "disassemble",
                 "peg-insert-side", "box-close", "hammer")


def _chain(x: float, y: float) -> str:
    if x > 1.0:
        return "far"
    # a comment and a multi-line return between the branches
    elif y > 1.0:
        return (
            "above"
        )
    elif x < -1.0:
        return "behind"
    else:
        return "here"


def _no_return(x: float) -> None:
    x + 1.0


def test_phase_tracer_numbers_the_returns_in_source_order() -> None:
    tracer = PhaseTracer(_chain)
    assert tracer.phases == 4
    assert tracer(2.0, 0.0) == ("far", 0)
    assert tracer(0.0, 2.0) == ("above", 1)
    assert tracer(-2.0, 0.0) == ("behind", 2)
    assert tracer(0.0, 0.0) == ("here", 3)
    assert PhaseTracer(_no_return).phases == 1 and PhaseTracer(_no_return)(1.0) == (None, 0)


def test_phase_tracer_restores_the_previous_trace_function() -> None:
    calls: list[str] = []

    def mine(frame, event, arg):  # type: ignore[no-untyped-def]
        calls.append(event)
        return None

    previous = sys.gettrace()
    sys.settrace(mine)
    try:
        PhaseTracer(_chain)(0.0, 0.0)
        assert sys.gettrace() is mine
    finally:
        sys.settrace(previous)


def test_merge_short_runs_gives_flickers_to_their_neighbour() -> None:
    flicker = np.array([0] * 5 + [1, 0] + [1] * 6 + [2] * 4)
    assert merge_short_runs(flicker, 3).tolist() == [0] * 7 + [1] * 6 + [2] * 4
    assert merge_short_runs(np.array([3, 0, 0, 0, 1, 1, 1]), 2).tolist() == [0, 0, 0, 0, 1, 1, 1]  # first: next
    assert merge_short_runs(np.array([0, 1, 2]), 5).tolist() == [1, 1, 1]  # shortest first, ties: earliest
    steady = np.array([0] * MIN_SEGMENT + [1] * MIN_SEGMENT)
    assert merge_short_runs(steady).tolist() == steady.tolist()


def test_every_task_has_a_registry_entry() -> None:
    from digail.envs.registry import ENV_SPECS
    from digail.experts.scripted import SCRIPTED_EXPERTS

    assert len(EPISODE_STEPS) == 50
    for task, steps in EPISODE_STEPS.items():
        spec = ENV_SPECS[env_id(task)]
        assert spec.max_episode_steps == steps and 100 <= steps <= 500 and spec.preset == "metaworld"
        assert env_id(task) in SCRIPTED_EXPERTS


def test_import_digail_does_not_import_metaworld() -> None:
    code = "import sys, digail; assert 'metaworld' not in sys.modules, 'imported eagerly'"
    subprocess.run([sys.executable, "-c", code], check=True)


def test_dataset_id_keeps_the_namespace() -> None:
    from digail.data.demos import default_dataset_id

    assert default_dataset_id("metaworld/pick-place-v3") == "digail/metaworld-pick-place/expert-v0"
    assert default_dataset_id("digail/FetchPickAndPlace-v4") == "digail/fetchpickandplace/expert-v0"


# ---- with Meta-World installed (the Makefile installs it) ----


@pytest.fixture(scope="module")
def metaworld():  # type: ignore[no-untyped-def]
    return pytest.importorskip("metaworld")


def _make(task: str = "pick-place-v3", **kwargs):  # type: ignore[no-untyped-def]
    from digail.envs import make_env

    return make_env(env_id(task), **kwargs)


@pytest.mark.mujoco
def test_the_tasks_are_meta_worlds(metaworld) -> None:  # type: ignore[no-untyped-def]
    assert set(EPISODE_STEPS) == set(metaworld.env_dict.ALL_V3_ENVIRONMENTS)


@pytest.mark.mujoco
def test_reset_draws_new_placements_reproducibly(metaworld) -> None:  # type: ignore[no-untyped-def]
    env = _make()
    first, info = env.reset(seed=3)
    assert first.shape == (39,) and env.observation_space.contains(first)
    assert info["subtask"] == 0 and info["is_success"] is False
    again, _ = env.reset(seed=3)
    other, _ = env.reset(seed=4)
    following, _ = env.reset()
    env.close()
    np.testing.assert_array_equal(first, again)
    for obs in (other, following):  # the object (4:7) and the goal (36:39) move between episodes
        assert np.linalg.norm(obs[4:7] - first[4:7]) > 1e-3 and np.linalg.norm(obs[36:39] - first[36:39]) > 1e-3


@pytest.mark.mujoco
def test_mt1_variation_draws_from_meta_worlds_fixed_set(metaworld) -> None:  # type: ignore[no-untyped-def]
    env = _make(variation="mt1")
    goals = {tuple(np.round(env.reset(seed=s)[0][36:39], 6)) for s in range(40)}
    env.close()
    bench = metaworld.MT1("pick-place-v3", seed=0)
    assert len(bench.train_tasks) == 50 and 10 < len(goals) <= 50


@pytest.mark.mujoco
def test_bad_variation_is_one_sentence(metaworld) -> None:  # type: ignore[no-untyped-def]
    from digail.errors import UserError

    with pytest.raises(UserError, match="variation must be random or mt1"):
        _make(variation="fixed")


@pytest.mark.mujoco
def test_steps_past_meta_worlds_limit_and_reward_convention(metaworld) -> None:  # type: ignore[no-untyped-def]
    """Meta-World's own env raises after 500 steps; digail's runs on (its time limit ends episodes); the shaped
    reward is never negative and nothing terminates."""
    from digail.envs.metaworld import MetaWorldEnv

    env = MetaWorldEnv("reach-v3", terminate_on_success=False)
    env.reset(seed=0)
    env.action_space.seed(0)
    rewards = []
    for _ in range(510):
        _, r, terminated, truncated, _ = env.step(env.action_space.sample())
        rewards.append(r)
        assert not terminated and not truncated
    env.close()
    assert min(rewards) >= 0.0


@pytest.mark.mujoco
def test_success_holds_from_the_first_successful_step(metaworld, monkeypatch) -> None:  # type: ignore[no-untyped-def]
    from digail.envs.metaworld import MetaWorldEnv

    env = MetaWorldEnv("reach-v3", terminate_on_success=False)
    env.reset(seed=0)
    real, flags = env.mw.step, iter([0.0, 1.0, 0.0, 0.0])

    def step(action):  # type: ignore[no-untyped-def]
        obs, r, terminated, truncated, info = real(action)
        return obs, r, terminated, truncated, {**info, "success": next(flags)}

    monkeypatch.setattr(env.mw, "step", step)
    steps = [env.step(np.zeros(4)) for _ in range(4)]
    assert [s[4]["is_success"] for s in steps] == [False, True, True, True]
    assert [s[2] for s in steps] == [False, False, False, False]  # played on: it never terminates
    env.close()


@pytest.mark.mujoco
def test_the_first_success_ends_the_episode(metaworld) -> None:  # type: ignore[no-untyped-def]
    env = _make()
    labels, success, observations = _expert_episode(env, 0)
    env.close()
    assert success and len(observations) < EPISODE_STEPS["pick-place-v3"] + 1


def _expert_episode(env, seed: int) -> tuple[np.ndarray, bool, list[np.ndarray]]:  # type: ignore[no-untyped-def]
    from digail.experts.metaworld import metaworld_expert

    obs, info = env.reset(seed=seed)
    labels, observations = [info["subtask"]], [obs]
    while True:
        obs, _, terminated, truncated, info = env.step(metaworld_expert(env))
        labels.append(info["subtask"])
        observations.append(obs)
        if terminated or truncated:
            return np.asarray(labels), bool(info["is_success"]), observations


@pytest.mark.mujoco
def test_pick_place_expert_succeeds_through_its_four_phases_in_order(metaworld) -> None:  # type: ignore[no-untyped-def]
    env = _make()
    for seed in range(3):
        labels, success, _ = _expert_episode(env, seed)
        merged = merge_short_runs(labels)
        runs = merged[np.r_[True, np.diff(merged) != 0]].tolist()
        assert success and runs[-1] == 3 and runs == sorted(runs), (seed, runs)
        assert len(labels) < EPISODE_STEPS["pick-place-v3"] + 1  # it ends at the first success
    env.close()


@pytest.mark.mujoco
def test_phase_is_the_branch_pick_places_expert_takes(metaworld) -> None:  # type: ignore[no-untyped-def]
    """The traced label against the branch conditions of Meta-World 3.1.1's pick-place expert, written out here
    (the library reads them from the expert's code instead)."""
    env = _make()
    labels, _, observations = _expert_episode(env, 0)
    env.close()
    expected = []
    for obs in observations:
        hand, gripper, puck = obs[:3], obs[3], obs[4:7] + np.array([-0.005, 0.0, 0.0])
        if np.linalg.norm(hand[:2] - puck[:2]) > 0.02:
            expected.append(0)
        elif abs(hand[2] - puck[2]) > 0.05 and puck[-1] < 0.04:
            expected.append(1)
        else:
            expected.append(2 if gripper > 0.73 else 3)
    assert labels.tolist() == expected and set(expected) == {0, 1, 2, 3}


@pytest.mark.mujoco
def test_expert_warnings_are_silenced(metaworld, capfd) -> None:  # type: ignore[no-untyped-def]
    import warnings

    env = _make()
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        _expert_episode(env, 0)
    env.close()
    assert not caught and "Constant(s) may be too high" not in capfd.readouterr().err


@pytest.mark.mujoco
@pytest.mark.parametrize("task", SHIPPED_TASKS)
def test_shipped_demonstrations_load_with_the_phases(task: str, metaworld) -> None:  # type: ignore[no-untyped-def]
    from digail.data.demos import default_dataset_id
    from digail.data.minari_io import load_dataset, shipped_dataset_ids
    from digail.data.validation import check_matches_env
    from digail.envs.metaworld import ExpertPhase

    ds_id = default_dataset_id(env_id(f"{task}-v3"))
    assert ds_id in shipped_dataset_ids()
    ds = load_dataset(ds_id)
    check_matches_env(ds, env_id(f"{task}-v3"))
    phases = ExpertPhase(f"{task}-v3").phases
    assert len(ds.trajs) == 50
    for t in ds.trajs:
        assert t.obs.dtype == np.float32 and t.obs.shape[1] == 39 and len(t) <= EPISODE_STEPS[f"{task}-v3"]
        assert t.subtasks is not None and 0 <= t.subtasks.min() <= t.subtasks.max() < phases
    assert {int(s) for t in ds.trajs for s in t.subtasks} == set(range(phases))


@pytest.mark.slow
@pytest.mark.mujoco
def test_a_frame_renders_headless(metaworld) -> None:  # type: ignore[no-untyped-def]
    env = _make(render_mode="rgb_array")
    env.reset(seed=0)
    frame = np.asarray(env.render())
    env.close()
    assert frame.ndim == 3 and frame.shape[2] == 3 and frame.dtype == np.uint8 and frame.std() > 5


@pytest.mark.slow
@pytest.mark.mujoco
def test_digail_video_records_a_task(metaworld, tmp_path) -> None:  # type: ignore[no-untyped-def]
    import imageio.v3 as iio

    from digail.cli import main

    vae = tmp_path / "vae"
    assert main(["pretrain", "--demos", "digail/metaworld-hammer/expert-v0", "--demos-episodes", "3", "--preset",
                 "smoke", "--out", str(vae)]) == 0
    assert main(["video", str(vae), "--max-steps", "12"]) == 0
    frames = iio.imread(vae / "videos" / "closed_loop.mp4")
    assert frames.shape[0] >= 12 and frames.shape[3] == 3 and frames.std() > 5


def _robomimic_file(trajs, path) -> None:  # type: ignore[no-untyped-def]
    """Meta-World episodes in robomimic's layout: the 39 numbers as obs/state, the actions, one done per demo."""
    import h5py

    with h5py.File(path, "w") as f:
        data = f.create_group("data")
        for i, t in enumerate(trajs):
            demo = data.create_group(f"demo_{i}")
            demo.create_dataset("obs/state", data=t.obs[:-1])
            demo.create_dataset("next_obs/state", data=t.obs[1:])
            demo.create_dataset("actions", data=t.acts)
            demo.create_dataset("rewards", data=np.zeros(len(t)))
            demo.create_dataset("dones", data=(np.arange(len(t)) == len(t) - 1).astype(np.int64))
            demo.attrs["num_samples"] = len(t)
        data.attrs["total"] = sum(len(t) for t in trajs)
        data.attrs["env_args"] = '{"env_name": "pick-place-v3", "type": 4, "env_kwargs": {}}'


def _lerobot_folder(trajs, folder) -> None:  # type: ignore[no-untyped-def]
    """Meta-World episodes as a LeRobot v3.0 dataset: one row per state with the action taken in it."""
    import json

    import pyarrow as pa
    import pyarrow.parquet as pq

    rows = [(i, k, t.obs[k], t.acts[k]) for i, t in enumerate(trajs) for k in range(len(t))]
    table = pa.table({
        "observation.state": pa.array([r[2].tolist() for r in rows], pa.list_(pa.float32(), 39)),
        "action": pa.array([r[3].tolist() for r in rows], pa.list_(pa.float32(), 4)),
        "timestamp": pa.array([r[1] / 80.0 for r in rows], pa.float32()),
        "frame_index": pa.array([r[1] for r in rows], pa.int64()),
        "episode_index": pa.array([r[0] for r in rows], pa.int64()),
        "index": pa.array(list(range(len(rows))), pa.int64()),
        "task_index": pa.array([0] * len(rows), pa.int64()),
    })
    (folder / "data" / "chunk-000").mkdir(parents=True)
    (folder / "meta").mkdir()
    pq.write_table(table, folder / "data" / "chunk-000" / "file-000.parquet")
    scalar = {"shape": [1], "names": None}
    features = {"observation.state": {"dtype": "float32", "shape": [39], "names": None},
                "action": {"dtype": "float32", "shape": [4], "names": None},
                "timestamp": {"dtype": "float32", **scalar},
                **{k: {"dtype": "int64", **scalar} for k in ("frame_index", "episode_index", "index", "task_index")}}
    (folder / "meta" / "info.json").write_text(json.dumps({"codebase_version": "v3.0", "fps": 80,
                                                           "features": features}))


@pytest.mark.slow
@pytest.mark.mujoco
def test_segmentations_export_to_robomimic_lerobot_and_csv(metaworld, tmp_path) -> None:  # type: ignore[no-untyped-def]
    """A VAE pre-trained on shipped Meta-World demonstrations segments the same episodes held in robomimic's and
    LeRobot's layouts and writes its codes into copies of them, and as a table."""
    import h5py
    import pyarrow.parquet as pq

    from digail.cli import main
    from digail.data.minari_io import load_dataset

    demos = "digail/metaworld-pick-place/expert-v0"
    trajs = load_dataset(demos).trajs[:3]
    _robomimic_file(trajs, tmp_path / "pp.hdf5")
    _lerobot_folder(trajs, tmp_path / "pp_lerobot")
    vae = tmp_path / "vae"
    assert main(["pretrain", "--demos", demos, "--demos-episodes", "3", "--preset", "smoke", "--out", str(vae)]) == 0
    assert main(["segment", str(vae), "--demos", str(tmp_path / "pp.hdf5"), "--export", "robomimic", "--names",
                 "reach", "carry", "--out", str(tmp_path / "pp_annotated.hdf5")]) == 0
    with h5py.File(tmp_path / "pp_annotated.hdf5", "r") as f:
        for i, t in enumerate(trajs):
            signals = f[f"data/demo_{i}/datagen_info/subtask_term_signals"]
            assert set(signals) == {"reach", "carry"} and all(len(signals[k]) == len(t) for k in signals)
    assert main(["segment", str(vae), "--demos", str(tmp_path / "pp_lerobot"), "--export", "lerobot", "--out",
                 str(tmp_path / "pp_lerobot_annotated")]) == 0
    frames = pq.read_table(tmp_path / "pp_lerobot_annotated" / "data" / "chunk-000" / "file-000.parquet")
    assert frames.num_rows == sum(len(t) for t in trajs)
    assert set(frames.column("subtask_index").to_pylist()) <= {0, 1}
    assert main(["segment", str(vae), "--demos", demos, "--export", "csv", "--out", str(tmp_path / "seg.csv")]) == 0
    lines = (tmp_path / "seg.csv").read_text().splitlines()
    assert lines[0] == "episode,start,end,code,name,reading" and len(lines) > len(trajs)


@pytest.mark.slow
@pytest.mark.mujoco
def test_every_task_runs_its_expert_with_phase_labels(metaworld) -> None:  # type: ignore[no-untyped-def]
    """Each of the 50 tasks is made through the registry, reset, and stepped by its expert, every label one of its
    expert's phases; between them the experts' labels take more than one value (the tracer reads real branches)."""
    from digail.envs.metaworld import phase_counts
    from digail.experts import expert_for

    counts, moved = phase_counts(), 0
    for task in EPISODE_STEPS:
        env = _make(task)
        policy, kind = expert_for(env_id(task))
        obs, info = env.reset(seed=0)
        labels = [info["subtask"]]
        for _ in range(40):
            obs, _, terminated, truncated, info = env.step(policy(env, obs))
            labels.append(info["subtask"])
            if terminated or truncated:
                break
        env.close()
        assert kind == "scripted" and all(0 <= lb < counts[task] for lb in labels), task
        moved += len(set(labels)) > 1
    assert moved >= 40, moved  # 45 of 50 here (two have one phase, three stay in their first 40 steps)
