"""Meta-World v3 tasks (`metaworld/<task>-v3`, e.g. `metaworld/pick-place-v3`): a Sawyer arm in MuJoCo, with the
phase of Meta-World's own scripted expert as the oracle sub-task label.

**Observation** (39 float64 numbers, Meta-World's goal-observable layout): the hand position (0:3), the gripper
opening (3), the first object's position and quaternion (4:11), a second object's (11:18), the same 18 numbers of the
previous step (18:36) and the goal position (36:39). **Action**: 4 numbers in [-1, 1], the hand's displacement and
the gripper effort. **Reward**: Meta-World's shaped reward (0-10 per step; the learner never sees it).

**Variation.** By default every reset draws a new object and goal placement from the env's random generator (reset
with `seed` reseeds it, so episode `i` of a seeded run is reproducible); `variation="mt1"` draws each episode's
placement from Meta-World's MT1 set instead (the 50 placements `metaworld.MT1(task, seed=mt1_seed)` fixes).

**Success.** `info["success"]` is Meta-World's test of the current state; `info["is_success"]` is true from the
first step at which it held, and that step ends the episode (`terminated`), as Meta-World's own evaluation ends it
(`terminate_on_success=False` plays on to the time limit instead; `is_success` then stays true). The last step's
`is_success` is the episode's success. The time limit is the task's `EPISODE_STEPS` (the registry entry's), set
from the expert's episodes; Meta-World's own 500-step limit, past which its env raises, is lifted.

Ending at success keeps the demonstrations to the expert's phases: played on, the expert holds the object at the
goal for the rest of the episode, a behaviour of its own (no motion) inside its last phase (measured in
docs/howto/metaworld.md).

**Oracle phase** in `info["subtask"]` (at the reset and after every step): which `return` statement of the
expert's `_desired_pos` (`metaworld.policies`) the current observation takes, numbered in source order
(`PhaseTracer`): Meta-World's experts are if/elif chains over distances, one return per phase. It is read by
tracing the expert's own code, so a new Meta-World version's experts label themselves. Some experts switch back
and forth between two neighbouring phases for a step or two (box-close between its first two);
`merge_short_runs(labels, MIN_SEGMENT)` merges such runs into their neighbour for scoring.

Meta-World is imported only when such an env is made (`pip install --no-deps metaworld==3.1.1`: it pins an older
MuJoCo, the project's runs it).
"""

from __future__ import annotations

import dis
import functools
import sys
import warnings
from collections.abc import Callable
from typing import Any, Literal

import gymnasium as gym
import numpy as np

NAMESPACE = "metaworld"
OBS_DIM = 39

EPISODE_STEPS: dict[str, int] = {
    "assembly-v3": 150, "basketball-v3": 250, "bin-picking-v3": 450, "box-close-v3": 250,
    "button-press-topdown-v3": 150, "button-press-topdown-wall-v3": 100, "button-press-v3": 100,
    "button-press-wall-v3": 150, "coffee-button-v3": 100, "coffee-pull-v3": 150, "coffee-push-v3": 100,
    "dial-turn-v3": 150, "disassemble-v3": 300, "door-close-v3": 200, "door-lock-v3": 200, "door-open-v3": 150,
    "door-unlock-v3": 150, "drawer-close-v3": 150, "drawer-open-v3": 150, "faucet-close-v3": 150,
    "faucet-open-v3": 100, "hammer-v3": 150, "hand-insert-v3": 150, "handle-press-side-v3": 100,
    "handle-press-v3": 100, "handle-pull-side-v3": 150, "handle-pull-v3": 200, "lever-pull-v3": 150,
    "peg-insert-side-v3": 250, "peg-unplug-side-v3": 300, "pick-out-of-hole-v3": 200, "pick-place-v3": 100,
    "pick-place-wall-v3": 200, "plate-slide-back-side-v3": 100, "plate-slide-back-v3": 150,
    "plate-slide-side-v3": 100, "plate-slide-v3": 100, "push-back-v3": 500, "push-v3": 150, "push-wall-v3": 150,
    "reach-v3": 100, "reach-wall-v3": 100, "shelf-place-v3": 200, "soccer-v3": 200, "stick-pull-v3": 250,
    "stick-push-v3": 100, "sweep-into-v3": 100, "sweep-v3": 200, "window-close-v3": 150, "window-open-v3": 150,
}
"""Every Meta-World v3 task by its name, with the time limit of its digail env (steps)."""

MIN_SEGMENT = 3
"""phase runs shorter than this (steps) are merged into their neighbour when scoring (`merge_short_runs`)"""


def env_id(task: str) -> str:
    """digail's id of a Meta-World task, e.g. pick-place-v3 -> metaworld/pick-place-v3."""
    return f"{NAMESPACE}/{task}"


def _metaworld() -> Any:
    try:
        import metaworld
    except ImportError as exc:
        from digail.errors import UserError

        raise UserError("Meta-World tasks need the metaworld package; install it with "
                        "`pip install --no-deps metaworld==3.1.1` (see docs/howto/metaworld.md).") from exc
    return metaworld


class PhaseTracer:
    """Which `return` statement of a function ran: the function's phase index for its arguments.

    The returns are numbered in source order (from the code object's instructions), so an if/elif chain with one
    return per branch numbers its branches 0, 1, ... A function without a return statement has one phase.
    """

    def __init__(self, fn: Callable[..., Any]) -> None:
        self.fn = fn
        self.code = fn.__code__
        lines = sorted({ins.positions.lineno for ins in dis.get_instructions(self.code)
                        if ins.opname.startswith("RETURN") and ins.positions is not None
                        and ins.positions.lineno is not None})
        self.return_lines: tuple[int, ...] = tuple(lines)

    @property
    def phases(self) -> int:
        """Number of phases (return statements; at least 1)."""
        return max(len(self.return_lines), 1)

    def __call__(self, *args: Any) -> tuple[Any, int]:
        """`fn(*args)` and the index of the return statement that produced it."""
        code, seen = self.code, [-1]

        def local(frame: Any, event: str, arg: Any) -> Any:
            if event == "return":
                seen[0] = frame.f_lineno
            return local

        def outer(frame: Any, event: str, arg: Any) -> Any:
            if frame.f_code is code:
                frame.f_trace_lines = False
                return local
            return None

        previous = sys.gettrace()
        sys.settrace(outer)
        try:
            result = self.fn(*args)
        finally:
            sys.settrace(previous)
        line = seen[0]
        return result, (self.return_lines.index(line) if line in self.return_lines else 0)


class ExpertPhase:
    """A Meta-World task's scripted expert (`metaworld.policies`) and the phase of its `_desired_pos`."""

    def __init__(self, task: str) -> None:
        from metaworld.policies import ENV_POLICY_MAP

        policy_cls: Any = ENV_POLICY_MAP[task]  # a concrete subclass of the abstract Policy
        self.policy = policy_cls()
        desired = getattr(type(self.policy), "_desired_pos", None)
        self.tracer = PhaseTracer(desired) if desired is not None else None

    @property
    def phases(self) -> int:
        """How many phases the expert has."""
        return self.tracer.phases if self.tracer is not None else 1

    def phase(self, obs: np.ndarray) -> int:
        """The phase the expert is in at observation `obs`."""
        if self.tracer is None:
            return 0
        return self.tracer(self.policy._parse_obs(obs))[1]

    def action(self, obs: np.ndarray) -> np.ndarray:
        """The expert's action (float32, clipped to [-1, 1] as the env clips it); its warning that a gain is too
        high for the action bounds is silenced."""
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            act = self.policy.get_action(obs)
        return np.clip(np.asarray(act, dtype=np.float32), -1.0, 1.0)


def merge_short_runs(labels: np.ndarray, min_len: int = MIN_SEGMENT) -> np.ndarray:
    """`labels` with every run shorter than `min_len` steps given to its neighbour (the previous run; the first
    run to the next), the shortest first, until none is left or one run remains."""
    out = np.asarray(labels).copy()
    while True:
        change = np.flatnonzero(np.diff(out)) + 1
        starts = np.concatenate([[0], change])
        ends = np.concatenate([change, [len(out)]])
        if len(starts) <= 1:
            return out
        lengths = ends - starts
        i = int(np.argmin(lengths))
        if lengths[i] >= min_len:
            return out
        out[starts[i]:ends[i]] = out[starts[i] - 1] if i > 0 else out[ends[i]]


class MetaWorldEnv(gym.Env):
    """One Meta-World v3 task with the goal observed, random placements per episode and phase labels (module doc).

    It holds Meta-World's env rather than wrapping it, so that `env.unwrapped` is this object and the expert reads
    the last observation (`last_obs`) and its own phase machine (`expert`) through it.
    """

    metadata: dict[str, Any] = {"render_modes": ["human", "rgb_array", "depth_array"], "render_fps": 80}

    def __init__(self, task: str, render_mode: str | None = None, variation: Literal["random", "mt1"] = "random",
                 mt1_seed: int = 0, terminate_on_success: bool = True, camera_name: str = "corner2",
                 width: int = 320, height: int = 320) -> None:
        metaworld = _metaworld()
        from digail.errors import UserError

        if task not in metaworld.env_dict.ALL_V3_ENVIRONMENTS:
            raise UserError(f"unknown Meta-World task {task!r}; the tasks are "
                            f"{', '.join(sorted(metaworld.env_dict.ALL_V3_ENVIRONMENTS))}.")
        if variation not in ("random", "mt1"):
            raise UserError(f"variation must be random or mt1, not {variation!r}.")
        cls = metaworld.env_dict.ALL_V3_ENVIRONMENTS[task]
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            self.mw: Any = cls(render_mode=render_mode, camera_name=camera_name, width=width, height=height)
        self.mw._partially_observable = False  # the goal in the observation, as Meta-World's MT benchmarks have it
        self.mw.__dict__.pop("sawyer_observation_space", None)  # a cached property of the observability
        self.mw._set_task_called = True
        self.mw._freeze_rand_vec = False
        self.mw.seeded_rand_vec = True  # placements from the env's generator, which reset(seed=...) reseeds
        self.mw.max_path_length = sys.maxsize  # digail's time limit ends episodes; Meta-World's would raise past 500
        self.task, self.variation, self.terminate_on_success = task, variation, bool(terminate_on_success)
        self.mt1_tasks: list[Any] = []
        if variation == "mt1":
            with warnings.catch_warnings():
                warnings.simplefilter("ignore")
                self.mt1_tasks = list(metaworld.MT1(task, seed=mt1_seed).train_tasks)
        self.render_mode = render_mode
        self.action_space = gym.spaces.Box(-1.0, 1.0, shape=(4,), dtype=np.float32)
        self.observation_space = gym.spaces.Box(-np.inf, np.inf, shape=(OBS_DIM,), dtype=np.float64)
        self.expert = ExpertPhase(task)
        self.last_obs = np.zeros(OBS_DIM)
        self.succeeded = False

    def reset(self, *, seed: int | None = None, options: dict[str, Any] | None = None
              ) -> tuple[np.ndarray, dict[str, Any]]:
        super().reset(seed=seed)
        if seed is not None:
            self.mw.seed(int(seed))
        if self.mt1_tasks:
            self.mw.set_task(self.mt1_tasks[int(self.np_random.integers(len(self.mt1_tasks)))])
        obs, info = self.mw.reset()
        self.last_obs = np.asarray(obs, dtype=np.float64)
        self.succeeded = False
        return self.last_obs.copy(), {**info, "subtask": self.expert.phase(self.last_obs), "is_success": False}

    def step(self, action: np.ndarray) -> tuple[np.ndarray, float, bool, bool, dict[str, Any]]:
        obs, reward, _, _, info = self.mw.step(np.clip(np.asarray(action, dtype=np.float32), -1.0, 1.0))
        self.last_obs = np.asarray(obs, dtype=np.float64)
        self.succeeded = self.succeeded or bool(info.get("success", False))
        info = {**info, "subtask": self.expert.phase(self.last_obs), "is_success": self.succeeded}
        return self.last_obs.copy(), float(reward), self.succeeded and self.terminate_on_success, False, info

    def render(self) -> Any:
        frame = self.mw.render()
        # Meta-World's cameras render upside down
        return np.ascontiguousarray(frame[::-1]) if isinstance(frame, np.ndarray) else frame

    def close(self) -> None:
        self.mw.close()


@functools.cache
def phase_counts() -> dict[str, int]:
    """Every task's number of expert phases (needs Meta-World)."""
    _metaworld()
    return {task: ExpertPhase(task).phases for task in EPISODE_STEPS}
