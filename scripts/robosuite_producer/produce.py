"""Scripted robosuite demonstrations in robomimic's layout, with MimicGen's sub-task signals kept aside as the oracle.

Runs in its own virtual environment (robosuite 1.5.2 needs mujoco <= 3.9 and numpy < 2), never digail's:

    python3 -m venv /path/rsvenv
    /path/rsvenv/bin/pip install -r scripts/robosuite_producer/requirements.txt
    /path/rsvenv/bin/python scripts/robosuite_producer/produce.py --task Stack --demos 50 --seed 0 --out stack.hdf5

It writes two files:

- `OUT` (e.g. `stack.hdf5`): the demonstrations as robomimic's robosuite pipeline leaves them (robosuite's
  collection, then robomimic's `dataset_states_to_obs.py`): `data/demo_<i>/{states, actions, rewards, dones}`,
  `obs/<key>` and `next_obs/<key>` for every low-dimensional key robomimic's `EnvRobosuite.get_observation` returns
  (`object` from robosuite's `object-state`, every `robot0_*` key but the proprio-state; joint positions and eef
  velocities switched on as robomimic does), the `model_file` and `num_samples` attributes per demonstration,
  `data.attrs["total"]` and `data.attrs["env_args"]` (robomimic's `EnvRobosuite.serialize()`: env_name,
  env_version, type 1, env_kwargs). `dones` follows `dataset_states_to_obs.py`'s default `--done_mode 0` (1 where
  the next state is a success). Observations are float32 (robomimic reads any float); states and actions stay
  float64, as robosuite stores them; datasets are gzip-compressed with HDF5's shuffle filter (lossless, read by any
  HDF5 >= 1.10 reader). With `--fixture` the `model_file` attribute is left out (see the README).
- `OUT` with `.oracle.hdf5` in place of `.hdf5`: per demonstration, `data/demo_<i>/datagen_info/subtask_term_signals/
  <name>`, computed as MimicGen's `prepare_src_dataset.py` computes them (reset to `states[t]`, `sim.forward()`,
  then the env interface's `get_subtask_term_signals()`), plus `task_success` (`env._check_success()` at
  `states[t]`), and `expert_phase`: the scripted expert's phase at each step (0 above the object, 1 down, 2 close,
  3 lift, 4 above the target, 5 down, 6 open), the labels of the segmentation benchmark. digail never reads this
  file as input: it is what the segmentation is scored against.

The signals, as MimicGen's robosuite env interfaces define them (NVlabs/mimicgen,
`mimicgen/env_interfaces/robosuite.py`):

- Stack (`MG_Stack`): `grasp` = `env._check_grasp(gripper=env.robots[0].gripper, object_geoms=env.cubeA)`; the task
  spec's two sub-tasks are grasp cube A, then place it on cube B (no signal: it ends with the demonstration).
- PickPlaceCan (`MG_PickPlace`, the can's entries): `grasp_can` = `env._check_grasp(gripper, object_geoms=
  can.contact_geoms)`; sub-tasks grasp the can, then place it in its bin (the last object in MimicGen's order has no
  place signal).

The experts are scripted in the space of robosuite's default OSC_POSE controller (delta position, no rotation,
gripper -1 open / +1 close): above the object, down, close, lift, above the target, down, open. A demonstration
ends a few steps after the task first succeeds (as robosuite's demonstration collection stops on success); one
that does not succeed within the horizon is discarded and counted.
"""

from __future__ import annotations

import argparse
import json
import time
from copy import deepcopy
from pathlib import Path

import h5py
import numpy as np
import robosuite
from robosuite.controllers import load_composite_controller_config

HORIZON = 400
"""steps a scripted attempt may take before it is discarded"""
AFTER_SUCCESS = 10
"""steps recorded after the task first succeeds (robosuite's collection waits for success to hold)"""


def make_env(task: str, seed: int | None = None):
    """The robosuite env with the kwargs robomimic's EnvRobosuite uses for low-dimensional data; `seed` seeds
    robosuite's own generator (object placements), without which every run differs."""
    kwargs = dict(seed=seed,
        robots="Panda", controller_configs=load_composite_controller_config(controller="BASIC"),
        has_renderer=False, has_offscreen_renderer=False, ignore_done=True, use_object_obs=True,
        use_camera_obs=False, camera_depths=False, reward_shaping=False, control_freq=20,
    )
    env = robosuite.make(task, **kwargs)
    for name in env.observation_names:  # robomimic switches these on (EnvRobosuite.__init__)
        if "joint_pos" in name or "eef_vel" in name:
            env.modify_observable(observable_name=name, attribute="active", modifier=True)
    return env, kwargs


def robomimic_obs(raw: dict) -> dict[str, np.ndarray]:
    """robomimic's EnvRobosuite.get_observation for low-dimensional obs: `object` plus the robot0_* keys."""
    out = {"object": np.array(raw["object-state"])}
    for key, value in raw.items():
        if key.startswith("robot0_") and not key.endswith("proprio-state"):
            out[key] = np.array(value)
    return out


def signals(task: str, env) -> dict[str, int]:
    """MimicGen's get_subtask_term_signals for the task (see the module docstring), on the env's current state."""
    gripper = env.robots[0].gripper
    if task == "Stack":
        return {"grasp": int(env._check_grasp(gripper=gripper, object_geoms=env.cubeA))}
    if task == "PickPlaceCan":
        env._check_success()  # MG_PickPlace calls it first (it refreshes objects_in_bins)
        can = env.objects[env.object_to_id["can"]]
        return {"grasp_can": int(env._check_grasp(gripper=gripper, object_geoms=[g for g in can.contact_geoms]))}
    raise ValueError(task)


class Expert:
    """A waypoint expert: a list of (target position function, gripper, done test) phases."""

    def __init__(self, task: str, env, rng: np.random.Generator):
        self.task, self.env, self.rng = task, env, rng
        self.phase, self.steps_in_phase = 0, 0
        self.gain = rng.uniform(8.0, 14.0)  # demonstrators differ in speed
        self.noise = 0.05

    def plan(self) -> list[tuple]:
        env = self.env
        if self.task == "Stack":
            obj = lambda: np.array(env.sim.data.body_xpos[env.cubeA_body_id])  # noqa: E731
            tgt = lambda: np.array(env.sim.data.body_xpos[env.cubeB_body_id])  # noqa: E731
            place_z = 0.025 + 0.02 + 0.01  # cube B's half-height + cube A's half-height + clearance
        else:
            obj = lambda: np.array(env.sim.data.body_xpos[env.obj_body_id["Can"]])  # noqa: E731
            tgt = lambda: np.array(env.target_bin_placements[env.object_to_id["can"]])  # noqa: E731
            place_z = 0.12
        hover = 0.10 + self.rng.uniform(-0.02, 0.03)
        grasp_dz = -0.005 if self.task == "Stack" else 0.02  # the can: its bin floor stops the fingertips lower
        return [
            (lambda: obj() + [0, 0, hover], -1, 0.01, 0),            # above the object
            (lambda: obj() + [0, 0, grasp_dz], -1, 0.006, 0),        # down to it
            (lambda: None, 1, None, 12),                             # close
            (lambda: obj() * [1, 1, 0] + [0, 0, tgt()[2] + hover + place_z], 1, 0.02, 0),  # lift
            (lambda: tgt() + [0, 0, hover + place_z], 1, 0.01, 0),   # above the target
            (lambda: tgt() + [0, 0, place_z], 1, 0.01, 0),           # down onto it
            (lambda: None, -1, None, 1000),                          # open, stay
        ]

    def act(self, plan: list[tuple], eef: np.ndarray) -> np.ndarray:
        target_fn, grip, tol, hold = plan[self.phase]
        target = target_fn()
        action = np.zeros(7)
        action[6] = grip
        if target is None:
            done = self.steps_in_phase >= hold
        else:
            err = target - eef
            action[:3] = np.clip(self.gain * err, -1, 1)
            done = np.linalg.norm(err) < tol or self.steps_in_phase > 60
        action[:3] += self.rng.normal(0, self.noise, 3)
        action[:6] = np.clip(action[:6], -1, 1)
        self.steps_in_phase += 1
        if done and self.phase < len(plan) - 1:
            self.phase, self.steps_in_phase = self.phase + 1, 0
        return action


def rollout(task: str, env, rng: np.random.Generator) -> dict | None:
    """One scripted demonstration: states, actions, obs, next_obs, rewards, dones; None if it fails."""
    raw = env.reset()
    xml = env.sim.model.get_xml()
    expert = Expert(task, env, rng)
    plan = expert.plan()
    states, actions, obs, next_obs, rewards, dones, phases = [], [], [], [], [], [], []
    succeeded_at = None
    for t in range(HORIZON):
        states.append(np.array(env.sim.get_state().flatten()))
        obs.append(robomimic_obs(raw))
        phases.append(expert.phase)  # the phase this step's action belongs to (act may move on to the next)
        a = expert.act(plan, np.array(raw["robot0_eef_pos"]))
        raw, r, _, _ = env.step(a)
        actions.append(a)
        next_obs.append(robomimic_obs(raw))
        rewards.append(float(r))  # env.reward(action) of the step, sparse (reward_shaping=False)
        success = bool(env._check_success())
        dones.append(int(success))  # dataset_states_to_obs.py --done_mode 0
        if success and succeeded_at is None:
            succeeded_at = t
        if succeeded_at is not None and t >= succeeded_at + AFTER_SUCCESS:
            break
    if succeeded_at is None:
        return None
    stack = lambda rows: {k: np.stack([r[k] for r in rows]) for k in rows[0]}  # noqa: E731
    return {"states": np.stack(states), "actions": np.stack(actions), "obs": stack(obs), "next_obs": stack(next_obs),
            "rewards": np.array(rewards), "dones": np.array(dones, dtype=np.int64), "model_file": xml,
            "phases": np.array(phases, dtype=np.int64)}


def oracle(task: str, env, states: np.ndarray) -> dict[str, np.ndarray]:
    """MimicGen's signals at every recorded state, computed as prepare_src_dataset.py does: reset to the state, then
    ask the env interface; plus the task's success at that state."""
    rows = []
    for s in states:
        env.sim.set_state_from_flattened(s)
        env.sim.forward()
        row = signals(task, env)
        row["task_success"] = int(env._check_success())
        rows.append(row)
    return {k: np.array([r[k] for r in rows], dtype=np.int64) for k in rows[0]}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--task", choices=["Stack", "PickPlaceCan"], required=True)
    parser.add_argument("--demos", type=int, default=50)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--out", type=Path, required=True)
    parser.add_argument("--fixture", action="store_true",
                        help="leave out each demonstration's model_file (40-50 kB of XML each) to keep a committed "
                             "fixture small; MimicGen's prepare_src_dataset.py needs it, so regenerate without this")
    args = parser.parse_args()
    oracle_path = args.out.with_name(args.out.name.replace(".hdf5", "") + ".oracle.hdf5")
    for p in (args.out, oracle_path):
        if p.exists():
            parser.error(f"{p} exists; choose another --out")
    rng = np.random.default_rng(args.seed)
    env, kwargs = make_env(args.task, args.seed)
    args.out.parent.mkdir(parents=True, exist_ok=True)
    t0, attempts, kept = time.time(), 0, []
    while len(kept) < args.demos:
        attempts += 1
        demo = rollout(args.task, env, rng)
        if demo is not None:
            demo["oracle"] = oracle(args.task, env, demo["states"])
            kept.append(demo)
    seconds = time.time() - t0
    steps = sum(len(d["actions"]) for d in kept)
    env_args = {"env_name": args.task, "env_version": robosuite.__version__, "type": 1,
                "env_kwargs": deepcopy(kwargs)}
    with h5py.File(args.out, "w", libver="latest") as f, h5py.File(oracle_path, "w", libver="latest") as g:
        data = f.create_group("data")
        for i, d in enumerate(kept):
            grp = data.create_group(f"demo_{i}")
            packed = dict(compression="gzip", shuffle=True)  # lossless; HDF5 >= 1.10 readers (h5py >= 2.7) undo it
            grp.create_dataset("actions", data=d["actions"], **packed)
            grp.create_dataset("states", data=d["states"], **packed)
            grp.create_dataset("rewards", data=d["rewards"])
            grp.create_dataset("dones", data=d["dones"])
            for part in ("obs", "next_obs"):
                for k, v in d[part].items():
                    grp.create_dataset(f"{part}/{k}", data=v.astype(np.float32), **packed)
            if not args.fixture:
                grp.attrs["model_file"] = d["model_file"]
            grp.attrs["num_samples"] = len(d["actions"])
            og = g.create_group(f"data/demo_{i}")
            for k, v in d["oracle"].items():
                where = "task_success" if k == "task_success" else f"datagen_info/subtask_term_signals/{k}"
                og.create_dataset(where, data=v)
            og.create_dataset("expert_phase", data=d["phases"])
        data.attrs["total"] = steps
        data.attrs["env_args"] = json.dumps(env_args, indent=4)
        g.attrs["producer"] = json.dumps({
            "task": args.task, "demos": args.demos, "seed": args.seed, "attempts": attempts,
            "robosuite": robosuite.__version__, "mujoco": __import__("mujoco").__version__,
            "numpy": np.__version__, "h5py": h5py.__version__, "seconds": round(seconds, 1), "steps": steps,
            "fixture": args.fixture, "signals": "MimicGen mimicgen/env_interfaces/robosuite.py at commit 72bd767",
        })
    print(f"{args.task}: {len(kept)} demonstrations kept of {attempts} attempts, {steps} steps "
          f"({steps / seconds:.0f} steps/s incl. oracle replay), wrote {args.out} and {oracle_path}")


if __name__ == "__main__":
    main()
