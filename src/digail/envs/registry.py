"""The registry of environments (one `EnvSpec` per env: its facts, metrics, preset and data size), their Gymnasium
registration, and `make_env`. How each env's experts are made lives with the experts (`digail.experts`); the
paper's numbers in `digail/paper.toml`."""

from __future__ import annotations

import contextlib
import difflib
import functools
import io
import warnings
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Any, Literal

import gymnasium as gym
import numpy as np

from digail.envs.circle_world import CircleWorldVecEnv
from digail.envs.fetch import GOAL as FETCH_GOAL
from digail.envs.fetch import OBJECT_POS as FETCH_OBJECT
from digail.envs.four_rooms import FourRoomsVecEnv, room_visits
from digail.envs.metaworld import EPISODE_STEPS as METAWORLD_STEPS
from digail.envs.metaworld import env_id as metaworld_id
from digail.envs.scene import FETCH as FETCH_SCENE
from digail.envs.scene import LANDMARK_ROUTE as ROUTE_SCENE
from digail.envs.scene import METAWORLD as METAWORLD_SCENE
from digail.envs.scene import SceneColumns
from digail.errors import UserError
from digail.paper import paper_return
from digail.preset import Preset, resolve_preset
from digail.user_envs import check_no_module, unnamed_env_hint
from digail.utils import mujoco_gl_error, one_line


@dataclass(frozen=True)
class StepMetric:
    """A task measure an env reports in every step's info, and how evaluation scores an episode by it."""

    info_key: str
    """key of the step info"""
    name: str
    """its name in eval.json (the mean over episodes of the per-episode value)"""
    reduce: Literal["sum", "any"] = "sum"
    """per episode: `sum` of the step values (a return), or `any` (1 if it was true at some step: a rate)"""


@dataclass(frozen=True)
class EnvSpec:
    """Everything digail knows about one environment; adding an environment is adding one of these."""

    env_id: str
    """Gymnasium id"""
    preset: str
    """name of its settings preset (`src/digail/presets/<name>.toml`; `paper-<name>`, where there is one, holds the
    paper's own)"""
    demo_episodes: int
    """demonstrations `digail demos` records by default (the paper's dataset size)"""
    entry_point: str | None = None
    """`module:Class` for envs digail registers itself (None: Gymnasium or gymnasium-robotics registers it)"""
    max_episode_steps: int | None = None
    """time limit of an env digail registers"""
    kwargs: tuple[tuple[str, Any], ...] = ()
    """keyword arguments of the entry point, as (name, value) pairs (one class serving several envs)"""
    compose_schedule: tuple[tuple[int, int], ...] | None = None
    """what `digail run` composes at the end: (oracle label, steps) pairs of a behaviour never demonstrated; the
    run translates labels into its own code ids through the segmentation's matching"""
    step_metrics: tuple[StepMetric, ...] = ()
    """task measures evaluation aggregates from the step infos (final-info rates such as `is_success` need no
    entry: `digail.eval.returns.RATE_KEYS`)"""
    eval_return: str | None = None
    """name of the `sum` step metric evaluation reports as its return (`mean_return`, `std_return`, the
    normalised return); None: the env reward's return"""
    reward_name: str = "env_return"
    """eval.json name of the env reward's mean return when `eval_return` takes `mean_return`"""
    auto_backend: Literal["sync", "subproc"] = "subproc"
    """the vector env `--train.backend auto` trains on when envpool does not cover the env: sync where a step
    costs less than a trip to a worker process (the grid and circle worlds, Pendulum; Fetch measured slower on
    subproc on 2 cores), else subproc"""
    envpool: bool = False
    """envpool has this env with Gymnasium's dynamics (`digail.envs.vector.EnvpoolVecEnv`, tested against it)"""
    name: str | None = None
    """what reports call it (None: its id)"""
    init_pieces: Callable[[np.ndarray], np.ndarray] | None = None
    """the function cutting a demonstration's observations into pieces that each take one code in the hard-EM
    start (`--vae.init-pieces env`; `function(obs (T, D)) -> (T,) piece numbers`); None: no such cut"""
    batched: Callable[..., Any] | None = None
    """the array implementation of N copies that the `sync` backend uses instead of stepping N envs in turn
    (`(env_id, num_envs, **kwargs)`; the same numbers, tested against `digail.envs.vector.VecEnv`)"""
    labels: tuple[str, ...] = ()
    """what each oracle sub-task label in `info["subtask"]` means, by label value (empty: the env gives none); the
    segmentation metrics score codes against these"""
    reward: Literal["cost", "task", "survival", "shaped"] = "cost"
    """the env reward's convention: `cost` never positive (minus a distance, a cost or a per-step penalty until
    success: higher is better, episodes do not end early for doing badly), `task` a step penalty with a positive
    reward on success that ends the episode, `survival` a bonus for every step alive that outweighs the rest, with
    episodes ended by falling (the episode length then carries reward information: log it, and prefer a positive
    GAIL reward, `--train.imitation.logits-to-reward positive`), `shaped` a non-negative progress reward that grows
    towards success (Meta-World's, 0-10 per step), the episode ending at success (prefer a step cost,
    `--train.imitation.logits-to-reward negative`)"""
    render: Literal["image", "mujoco", "pygame", "none"] = "mujoco"
    """how `render_mode="rgb_array"` draws a frame: `image` the env's own array (no extra package), `mujoco`
    offscreen MuJoCo (`MUJOCO_GL` must be set before MuJoCo is imported: `digail.utils.ensure_offscreen_gl`),
    `pygame` through pygame (an optional package), `none` it cannot draw"""
    state_figure: Literal["four_rooms", "pendulum"] | None = None
    """the env's own figure of the state space a run folder gets beside the generic ones (`viz.run_figures`):
    the Four Rooms code maps and paths, or Pendulum's code map over angle and velocity"""
    gait_features: tuple[int, int] | None = None
    """observation indices of the hip joint's angle and angular velocity whose phase labels a locomotion gait
    (`digail.eval.gait`; Gymnasium v5 layouts, default options); None: no gait phase"""
    relative_view: str | None = None
    """`module:function` mapping raw observations (n, D) to what D sees under `--train.imitation.disc-obs relative`:
    relations between the things in the scene instead of where they are (torch tensors in and out); None: the env has
    none"""
    goal_columns: tuple[slice, slice] | None = None
    """(the desired goal's columns, the columns of what meets it) in the flat observation, for
    relabelling a demonstration's goal with where it took the object later (`--train.imitation.relabel-goals`);
    None: the env is not goal-conditioned"""
    scene: SceneColumns | None = None
    """the observation columns of the end-effector, object and goal and the end-effector's move actions, which
    `digail generate` transforms and tracks demonstrated paths with; None: the env does not state them"""

    @property
    def paper_return(self) -> tuple[float, float] | None:
        """Directed-Info GAIL's mean return and std in the paper (`digail/paper.toml`: Table 1, or Table 2's dense
        return for Fetch), which reports print beside a run's; None where the paper has no number for the env."""
        return paper_return(self.env_id)

    def tracked_info_keys(self) -> tuple[str, ...]:
        """Info keys an episode loop records per step for the step metrics."""
        return tuple(m.info_key for m in self.step_metrics)

    def spaces(self) -> tuple[gym.Space, gym.Space]:
        """The observation and action spaces (`env_spaces`: the env is made once per process, then remembered)."""
        return env_spaces(self.env_id)


ENV_SPECS: dict[str, EnvSpec] = {spec.env_id: spec for spec in (
    EnvSpec("digail/FourRooms-v0", "four-rooms", 300, "digail.envs.four_rooms:FourRoomsEnv", 64,
            auto_backend="sync", name="Four Rooms",
            batched=FourRoomsVecEnv, init_pieces=room_visits,
            labels=("top corridor", "right corridor", "bottom corridor", "left corridor", "apple"),
            reward="task", render="image", state_figure="four_rooms"),
    # Circle-World: counter-clockwise first, then clockwise, the reversed order of the demonstrations
    EnvSpec("digail/CircleWorld-v0", "circle-world", 100, "digail.envs.circle_world:CircleWorldEnv", 120,
            compose_schedule=((1, 60), (0, 60)), auto_backend="sync", name="Circle-World",
            batched=CircleWorldVecEnv, labels=("clockwise", "counter-clockwise"), render="image"),
    # gymnasium-robotics is imported only when this one is made (digail.envs.fetch), and so is the expert's module
    # The paper's Table 2 measure is the dense return; the sparse one, success and grasp rates stand beside it
    EnvSpec("digail/FetchPickAndPlace-v4", "fetch", 500, "digail.envs.fetch:FlatFetchPickAndPlace", 50,
            step_metrics=(StepMetric("dense_reward", "dense_return", "sum"),
                          StepMetric("grasped", "grasp_rate", "any"), StepMetric("lifted", "lift_rate", "any")),
            eval_return="dense_return", reward_name="sparse_return", auto_backend="sync", name="Fetch pick-and-place",
            labels=("reach", "grasp", "carry", "place"), relative_view="digail.envs.fetch:relative_view",
            goal_columns=(FETCH_GOAL, FETCH_OBJECT), scene=FETCH_SCENE),
    # the same task observed without horizontal positions (relations only): D's view is then all of it
    EnvSpec("digail/FetchPickAndPlaceRelative-v4", "fetch", 50, "digail.envs.fetch:RelativeFetchPickAndPlace", 50,
            step_metrics=(StepMetric("dense_reward", "dense_return", "sum"),
                          StepMetric("grasped", "grasp_rate", "any"), StepMetric("lifted", "lift_rate", "any")),
            eval_return="dense_return", reward_name="sparse_return", auto_backend="sync",
            name="Fetch pick-and-place, relative observation", labels=("reach", "grasp", "carry", "place")),
    EnvSpec("FetchPickAndPlace-v4", "fetch", 500),
    # four legs, one per landmark; `order=...` (make_env) sets a route the demonstrations never showed
    EnvSpec("digail/LandmarkRoute-v0", "landmark-route", 100, "digail.envs.landmark_route:LandmarkRouteEnv", 400,
            step_metrics=(StepMetric("leg_done", "legs_done", "sum"), StepMetric("wrong_visit", "wrong_visits", "sum")),
            auto_backend="sync", name="Landmark route",
            labels=("north-east", "north-west", "south-west", "south-east"), render="image",
            relative_view="digail.envs.landmark_route:relative_view", scene=ROUTE_SCENE),
    # the segmentation benchmark's synthetic courses (kwargs pick the course): the defaults, no tuned preset; the
    # label is the index of the current waypoint, as many as the course has
    EnvSpec("digail/WaypointCourse-v0", "default", 20, "digail.envs.waypoints:WaypointCourseEnv",
            auto_backend="sync", render="none"),
    EnvSpec("Pendulum-v1", "pendulum", 25, auto_backend="sync", render="pygame", state_figure="pendulum"),
    EnvSpec("InvertedPendulum-v5", "invertedpendulum", 25, envpool=True, reward="survival"),
    EnvSpec("Hopper-v5", "hopper", 50, envpool=True, reward="survival", gait_features=(2, 8)),
    EnvSpec("Walker2d-v5", "walker2d", 50, envpool=True, reward="survival", gait_features=(2, 11)),
    # every Meta-World v3 task (digail.envs.metaworld), labelled by its scripted expert's phase; Meta-World is
    # imported only when one is made
    *(EnvSpec(metaworld_id(task), "metaworld", 50, "digail.envs.metaworld:MetaWorldEnv", steps,
              kwargs=(("task", task),), auto_backend="sync", name=f"Meta-World {task[:-3]}", reward="shaped",
              scene=METAWORLD_SCENE)
      for task, steps in METAWORLD_STEPS.items()),
)}
"""The environments digail has settings, demonstrations sizes or experts for, by id."""


def parse_env_args(items: Sequence[str]) -> dict[str, Any]:
    """`--env-arg KEY=VALUE ...` as keyword arguments: a value that reads as JSON is taken as such (2, 0.5, true,
    [3, 2]), anything else as text (order=3,2,1,0 stays the text the env parses)."""
    import json

    out: dict[str, Any] = {}
    for item in items:
        key, sep, value = item.partition("=")
        if not sep or not key.strip().isidentifier():
            raise UserError(f"--env-arg {item!r} is not KEY=VALUE; pass e.g. --env-arg order=3,2,1,0.")
        try:
            out[key.strip()] = json.loads(value)
        except ValueError:
            out[key.strip()] = value
    return out


def env_spec(env_id: str) -> EnvSpec | None:
    """The registry entry of `env_id`, or None for an environment digail has no entry for."""
    return ENV_SPECS.get(env_id)


@functools.cache
def env_spaces(env_id: str) -> tuple[gym.Space, gym.Space]:
    """`env_id`'s observation and action spaces; the env is made (`make_env`) and closed once per process, since
    Gymnasium's registry does not state spaces without making the env."""
    env = make_env(env_id)
    try:
        return env.observation_space, env.action_space
    finally:
        env.close()


def init_pieces_fn(env_id: str | None) -> Callable[[np.ndarray], np.ndarray] | None:
    """The function `env_id`'s entry names to cut demonstrations into pieces (`EnvSpec.init_pieces`), or None."""
    spec = ENV_SPECS.get(env_id or "")
    if spec is None or spec.init_pieces is None:
        return None
    return spec.init_pieces


def tracked_info_keys(env: gym.Env | str | None) -> tuple[str, ...]:
    """The per-step info keys of an env's step metrics (empty for an env without an entry or metrics)."""
    env_id = env if isinstance(env, str) or env is None else getattr(env.spec, "id", None)
    spec = ENV_SPECS.get(env_id or "")
    return spec.tracked_info_keys() if spec is not None else ()


def env_preset(env_id: str | None) -> str | None:
    """The name of `env_id`'s own preset (None for an env without an entry)."""
    spec = ENV_SPECS.get(env_id or "")
    return spec.preset if spec is not None else None


def preset_for(env_id: str | None, name: str | None = None) -> Preset:
    """The preset called `name`, else the one of `env_id`'s entry (the defaults for an env without one)."""
    return resolve_preset(name, env_preset(env_id))


def register_envs() -> None:
    """Register digail's own envs (the entries with an entry point) with Gymnasium (idempotent)."""
    for spec in ENV_SPECS.values():
        if spec.entry_point is not None and spec.env_id not in gym.registry:
            gym.register(id=spec.env_id, entry_point=spec.entry_point, max_episode_steps=spec.max_episode_steps,
                         kwargs=dict(spec.kwargs))


def make_env(env_id: str, **kwargs: Any) -> gym.Env:
    """`gym.make(env_id, **kwargs)` that reports an unknown or unavailable id as one `UserError` sentence.

    digail's own envs are registered by importing `digail`; robotics ids (e.g. FetchPickAndPlace-v4) are
    registered on demand by importing `gymnasium_robotics` when it is installed.
    """
    env_id = check_no_module(env_id)  # Gymnasium would import an id's `module:` part
    register_envs()
    for attempt in range(2):
        try:
            _check_versioned(env_id)
            with warnings.catch_warnings():  # Gymnasium's own notice of an old version: the error says it in one line
                warnings.simplefilter("ignore", DeprecationWarning)
                return gym.make(env_id, **kwargs)
        except (gym.error.NameNotFound, gym.error.NamespaceNotFound, gym.error.VersionNotFound) as exc:
            if attempt == 0 and _register_robotics():
                continue
            raise UserError(f"unknown environment id {env_id!r}; {_known_ids_hint(env_id)}.") from exc
        except gym.error.DependencyNotInstalled as exc:
            first = str(exc).strip().splitlines()[0] if str(exc).strip() else type(exc).__name__
            raise UserError(f"environment {env_id!r} needs a package that is not installed ({first}).") \
                from exc
        except gym.error.Error as exc:
            raise UserError(f"could not create environment {env_id!r}: {one_line(exc)}.") from exc
        except (RuntimeError, AttributeError, ImportError, OSError) as exc:
            gl = mujoco_gl_error()  # a MuJoCo env whose renderer setting stops MuJoCo from loading
            if gl is not None:
                raise gl from exc
            raise
    raise AssertionError("unreachable")


def _check_versioned(env_id: str) -> None:
    """Refuse an id Gymnasium resolves to another one (no version: its latest), which datasets, run folders and
    expert lookups would then name differently from the env that ran."""
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", DeprecationWarning)
        try:
            spec = gym.spec(env_id)
        except gym.error.Error:
            versions = [k for k in gym.registry if k.rpartition("-v")[0] == env_id and k.rpartition("-v")[2].isdigit()]
            if versions:  # `gym.make` would quietly take the latest
                latest = max(versions, key=lambda k: int(k.rpartition("-v")[2]))
                raise UserError(f"environment id {env_id!r} names no version; pass {latest!r}.") from None
            raise
    if spec.id != env_id:
        raise UserError(f"environment id {env_id!r} names no version; pass {spec.id!r}.")


def _register_robotics() -> bool:
    try:
        # its import prints a version notice to stderr; keep the CLI's error output to one line
        with contextlib.redirect_stderr(io.StringIO()):
            import gymnasium_robotics
    except ImportError:
        return False
    except (RuntimeError, AttributeError, OSError) as exc:  # it imports MuJoCo, which reads MUJOCO_GL
        gl = mujoco_gl_error()
        if gl is not None:
            raise gl from exc
        raise
    gym.register_envs(gymnasium_robotics)
    return True


def _known_ids_hint(env_id: str) -> str:
    if (hint := unnamed_env_hint(env_id)) is not None:
        return hint
    known = sorted(gym.registry)
    close = difflib.get_close_matches(env_id, known, n=3, cutoff=0.6)
    if close:
        return "did you mean " + " or ".join(close)
    return "known ids include digail/FourRooms-v0, digail/CircleWorld-v0, Pendulum-v1 and Hopper-v5"


def check_env_id(env_id: str) -> None:
    """Raise a UserError unless `env_id` is an env digail has an entry for or Gymnasium can make (the env is not
    built: cheap enough to check many ids before long work starts)."""
    if env_id in ENV_SPECS:
        return
    env_id = check_no_module(env_id)  # Gymnasium would import an id's `module:` part
    register_envs()
    for attempt in range(2):
        try:
            _check_versioned(env_id)
            return
        except gym.error.Error:
            if attempt == 0 and _register_robotics():
                continue
    raise UserError(f"unknown environment id {env_id!r}; {_known_ids_hint(env_id)}.")
