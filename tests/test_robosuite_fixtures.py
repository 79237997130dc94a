"""The robosuite fixtures (scripts/robosuite_producer/produce.py: scripted Stack and PickPlaceCan demonstrations
in robomimic's layout, MimicGen's signals in a separate oracle file) import as robomimic files, and their oracle
parses by MimicGen's rule."""

from __future__ import annotations

import json
from pathlib import Path

import h5py
import numpy as np
import pytest

from digail.data.importers import read_demonstrations
from digail.data.robomimic import SIGNALS_PATH

FIXTURES = Path(__file__).resolve().parent / "data" / "robosuite"
CASES = {"stack": ("Stack", 50, 6317, "grasp"), "pickplacecan": ("PickPlaceCan", 10, 1628, "grasp_can")}
OBS_KEYS = ["object", "robot0_eef_pos", "robot0_eef_quat", "robot0_eef_quat_site", "robot0_gripper_qpos",
            "robot0_gripper_qvel", "robot0_joint_acc", "robot0_joint_pos", "robot0_joint_pos_cos",
            "robot0_joint_pos_sin", "robot0_joint_vel"]


@pytest.mark.parametrize("name", sorted(CASES))
def test_fixture_imports_as_robomimic(name):
    env_name, demos, steps, _ = CASES[name]
    im = read_demonstrations(FIXTURES / f"{name}.hdf5")
    assert im.fmt == "robomimic" and len(im.trajs) == demos
    assert im.episode_keys == [f"demo_{i}" for i in range(demos)]
    assert im.metadata["obs_keys"] == OBS_KEYS  # every low-dimensional key robomimic's EnvRobosuite returns
    assert im.metadata["env_args"]["env_name"] == env_name and im.metadata["env_args"]["type"] == 1
    object_dim = 23 if name == "stack" else 14
    for t in im.trajs:
        assert t.obs.shape[1] == object_dim + 3 + 4 + 4 + 2 + 2 + 5 * 7 and t.acts.shape[1] == 7
        assert t.subtasks is None  # the oracle lives in its own file, never read as input
        assert not t.terminated  # robomimic's demonstrations are kept as truncated
    assert sum(len(t) for t in im.trajs) == steps  # next_obs gives the state after the last action
    with h5py.File(FIXTURES / f"{name}.hdf5", "r") as f:
        assert int(f["data"].attrs["total"]) == steps
        demo = f["data/demo_0"]
        assert demo["states"].dtype == np.float64 and demo["obs/object"].dtype == np.float32
        assert demo.attrs["num_samples"] == demo["actions"].shape[0] == demo["dones"].shape[0]
        assert SIGNALS_PATH.split("/")[0] not in demo


@pytest.mark.parametrize("name", sorted(CASES))
def test_oracle_parses_by_mimicgens_rule(name):
    env_name, demos, _, signal = CASES[name]
    with h5py.File(FIXTURES / f"{name}.hdf5", "r") as f, h5py.File(FIXTURES / f"{name}.oracle.hdf5", "r") as g:
        producer = json.loads(g.attrs["producer"])
        assert producer["task"] == env_name and producer["robosuite"] == "1.5.2" and producer["mujoco"] == "3.9.0"
        for i in range(demos):
            n = f[f"data/demo_{i}/actions"].shape[0]
            grasp = g[f"data/demo_{i}/{SIGNALS_PATH}/{signal}"][()]
            success = g[f"data/demo_{i}/task_success"][()]
            assert len(grasp) == len(success) == n and set(np.unique(grasp)) <= {0, 1}
            first = int(np.flatnonzero(np.diff(grasp))[0]) + 1  # MimicGen: the first 0 -> 1 ends the grasp
            assert grasp[0] == 0 and 0 < first < n - 1
            assert success[first:].any() and not success[:first].any()  # grasped before it is done
            # the gripper was commanded closed before the fingers touched (5-7 steps at 20 Hz)
            close = int(np.flatnonzero(f[f"data/demo_{i}/actions"][:, 6] > 0)[0])
            assert 3 <= first - close <= 10
