"""The registry of environments (one `EnvSpec` per env: settings, data size, experts, metrics), their Gymnasium
registration, and `make_env`."""

from __future__ import annotations

import contextlib
import difflib
import importlib
import io
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any, Literal

import gymnasium as gym
import numpy as np

from digail.config import Preset, TrainConfig, VAEConfig, get_preset
from digail.errors import UserError
from digail.utils import one_line


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
class ExpertSpec:
    """How `digail expert` trains the Stable-Baselines3 expert of one environment (why each recipe is as it is:
    docs/experiments.md#rl-experts)."""

    steps: int
    """default budget of environment steps"""
    target: float
    """mean return over 50 episodes the expert should reach (the project's acceptance bar)"""
    algo: str = "ppo"
    """SB3 algorithm: "ppo" (with VecNormalize) or "sac" (raw observations, replay buffer)"""
    n_envs: int = 8
    """parallel copies of the env in one process (DummyVecEnv)"""
    ppo: dict[str, Any] = field(default_factory=dict)
    """keyword arguments of `stable_baselines3.PPO` (learning_rate may be ('linear', lr0))"""
    sac: dict[str, Any] = field(default_factory=dict)
    """keyword arguments of `stable_baselines3.SAC` (algo "sac")"""
    net_arch: tuple[int, ...] = (64, 64)
    """hidden sizes of the policy and of the (separate) value / Q nets"""
    activation: str = "tanh"
    """hidden activation: tanh or relu"""
    log_std_init: float = 0.0
    """initial log standard deviation of the Gaussian policy"""
    use_sde: bool = False
    """generalised state-dependent exploration"""
    norm_reward: bool = True
    """normalise rewards during training, PPO only (evaluation always reports raw returns)"""
    gamma: float = 0.99
    """discount, shared by the algorithm and the reward normaliser"""
    checkpoint_every: int = 50_000
    """environment steps between resumable checkpoints"""
    eval_every: int = 50_000
    """environment steps between periodic evaluations (which also pick best_expert.pt)"""
    eval_episodes: int = 10
    """episodes of each periodic evaluation"""
    stop_at: float | None = None
    """stop early once a periodic evaluation reaches this mean return (None: run the whole budget)"""


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
    scripted_expert: str | None = None
    """`module:function` of its scripted expert, `function(env) -> action` (a name, not the function, because the
    experts sit above the envs; `digail.experts.scripted` resolves it); None: no scripted expert"""
    rl_expert: ExpertSpec | None = None
    """how `digail expert` trains its RL expert (None: no recipe)"""
    name: str | None = None
    """what reports call it (None: its id)"""
    paper_return: tuple[float, float] | None = None
    """Directed-Info GAIL's mean return and std in the paper (Table 1, 300 episodes; Fetch: Table 2, the dense
    return over 100 episodes), which reports print beside a run's; the paper used the -v0/-v2 versions of the
    MuJoCo envs (None: the paper has no number for it)"""
    init_pieces: str | None = None
    """`module:function` cutting a demonstration's observations into pieces that each take one code in the
    hard-EM start (`--vae.init-pieces env`; `function(obs (T, D)) -> (T,) piece numbers`); None: no such cut"""
    batched: str | None = None
    """`module:Class` of an array implementation of N copies that the `sync` backend uses instead of stepping N
    envs in turn (`(env_id, num_envs, **kwargs)`; the same numbers, tested against `digail.envs.vector.VecEnv`)"""

    def tracked_info_keys(self) -> tuple[str, ...]:
        """Info keys an episode loop records per step for the step metrics."""
        return tuple(m.info_key for m in self.step_metrics)


_LOCOMOTION_PPO: dict[str, Any] = {
    "n_steps": 512,  # x 8 envs = 4096 transitions per update
    "batch_size": 256,
    "n_epochs": 10,
    "learning_rate": ("linear", 3e-4),
    "gae_lambda": 0.95,
    "clip_range": 0.2,
    "ent_coef": 0.0,
    "vf_coef": 0.5,
    "max_grad_norm": 0.5,
}

ENV_SPECS: dict[str, EnvSpec] = {spec.env_id: spec for spec in (
    EnvSpec("digail/FourRooms-v0", "four-rooms", 300, "digail.envs.four_rooms:FourRoomsEnv", 64,
            auto_backend="sync", scripted_expert="digail.experts.scripted:four_rooms_expert", name="Four Rooms",
            batched="digail.envs.four_rooms:FourRoomsVecEnv", init_pieces="digail.envs.four_rooms:room_visits"),
    # Circle-World: counter-clockwise first, then clockwise, the reversed order of the demonstrations
    EnvSpec("digail/CircleWorld-v0", "circle-world", 100, "digail.envs.circle_world:CircleWorldEnv", 120,
            compose_schedule=((1, 60), (0, 60)), auto_backend="sync",
            scripted_expert="digail.experts.scripted:circle_expert", name="Circle-World",
            batched="digail.envs.circle_world:CircleWorldVecEnv"),
    # gymnasium-robotics is imported only when this one is made (digail.envs.fetch), and so is the expert's module
    # The paper's Table 2 measure is the dense return; the sparse one, success and grasp rates stand beside it
    EnvSpec("digail/FetchPickAndPlace-v4", "fetch", 500, "digail.envs.fetch:FlatFetchPickAndPlace", 50,
            step_metrics=(StepMetric("dense_reward", "dense_return", "sum"),
                          StepMetric("grasped", "grasp_rate", "any"), StepMetric("lifted", "lift_rate", "any")),
            eval_return="dense_return", reward_name="sparse_return", auto_backend="sync",
            scripted_expert="digail.experts.fetch:fetch_expert", name="Fetch pick-and-place",
            paper_return=(-11.74, 5.87)),
    EnvSpec("FetchPickAndPlace-v4", "fetch", 500),
    # the segmentation benchmark's synthetic courses (kwargs pick the course): the defaults, no tuned preset
    EnvSpec("digail/WaypointCourse-v0", "default", 20, "digail.envs.waypoints:WaypointCourseEnv",
            auto_backend="sync"),
    # SAC as in the RL-Zoo's entry (learning rate 1e-3, SB3's other defaults); the replay buffer holds the
    # whole budget; 64x64 nets keep one gradient step per env step affordable on a CPU
    EnvSpec("Pendulum-v1", "pendulum", 25, auto_backend="sync", paper_return=(-125.39, 103.75), rl_expert=ExpertSpec(
        algo="sac", steps=20_000, target=-150.0, n_envs=1, net_arch=(64, 64), activation="relu",
        sac={"learning_rate": 1e-3, "buffer_size": 200_000},
        checkpoint_every=5_000, eval_every=2_500, eval_episodes=50, stop_at=None)),
    # balancing is easy: plain PPO with small nets
    EnvSpec("InvertedPendulum-v5", "invertedpendulum", 25, envpool=True, paper_return=(1000.0, 14.97),
            rl_expert=ExpertSpec(
        steps=300_000, target=1000.0, n_envs=8,
        ppo={"n_steps": 256, "batch_size": 64, "n_epochs": 10, "learning_rate": 3e-4, "gae_lambda": 0.95,
             "clip_range": 0.2, "ent_coef": 0.0},
        checkpoint_every=20_000, eval_every=20_000, eval_episodes=20, stop_at=1000.0)),
    EnvSpec("Hopper-v5", "hopper", 50, envpool=True, paper_return=(3662.1, 21.7), rl_expert=ExpertSpec(
        steps=3_000_000, target=3000.0, ppo=_LOCOMOTION_PPO, net_arch=(256, 256), log_std_init=-0.5,
        checkpoint_every=100_000, eval_every=100_000, stop_at=3300.0)),
    EnvSpec("Walker2d-v5", "walker2d", 50, envpool=True, paper_return=(5083.9, 356.3), rl_expert=ExpertSpec(
        steps=5_000_000, target=4000.0, ppo=_LOCOMOTION_PPO, net_arch=(256, 256), log_std_init=-0.5,
        checkpoint_every=100_000, eval_every=100_000, stop_at=4400.0)),
)}
"""The environments digail has settings, demonstrations sizes or experts for, by id."""


def env_spec(env_id: str) -> EnvSpec | None:
    """The registry entry of `env_id`, or None for an environment digail has no entry for."""
    return ENV_SPECS.get(env_id)


def resolve(ref: str) -> Any:
    """The object an entry names as `module:name` (imported only now: the entries name code above or beside the
    registry, e.g. experts and array envs)."""
    module, name = ref.split(":")
    return getattr(importlib.import_module(module), name)


def init_pieces_fn(env_id: str | None) -> Callable[[np.ndarray], np.ndarray] | None:
    """The function `env_id`'s entry names to cut demonstrations into pieces (`EnvSpec.init_pieces`), or None."""
    spec = ENV_SPECS.get(env_id or "")
    if spec is None or spec.init_pieces is None:
        return None
    fn: Callable[[np.ndarray], np.ndarray] = resolve(spec.init_pieces)
    return fn


def rl_expert_envs() -> list[str]:
    """The envs with an RL expert recipe, in registry order."""
    return [spec.env_id for spec in ENV_SPECS.values() if spec.rl_expert is not None]


def tracked_info_keys(env: gym.Env | str | None) -> tuple[str, ...]:
    """The per-step info keys of an env's step metrics (empty for an env without an entry or metrics)."""
    env_id = env if isinstance(env, str) or env is None else getattr(env.spec, "id", None)
    spec = ENV_SPECS.get(env_id or "")
    return spec.tracked_info_keys() if spec is not None else ()


def preset_for(env_id: str | None, name: str | None = None) -> Preset:
    """The preset called `name`, else the one of `env_id`'s entry (the defaults for an env without one)."""
    spec = ENV_SPECS.get(env_id or "")
    if name is None:
        if spec is None:
            return Preset(VAEConfig(), TrainConfig())
        name = spec.preset
    return get_preset(name, spec.preset if spec is not None else None)


def register_envs() -> None:
    """Register digail's own envs (the entries with an entry point) with Gymnasium (idempotent)."""
    for spec in ENV_SPECS.values():
        if spec.entry_point is not None and spec.env_id not in gym.registry:
            gym.register(id=spec.env_id, entry_point=spec.entry_point, max_episode_steps=spec.max_episode_steps)


def make_env(env_id: str, **kwargs: Any) -> gym.Env:
    """`gym.make(env_id, **kwargs)` that reports an unknown or unavailable id as one `UserError` sentence.

    digail's own envs are registered by importing `digail`; robotics ids (e.g. FetchPickAndPlace-v4) are
    registered on demand by importing `gymnasium_robotics` when it is installed.
    """
    register_envs()
    for attempt in range(2):
        try:
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
    raise AssertionError("unreachable")


def _register_robotics() -> bool:
    try:
        # its import prints a version notice to stderr; keep the CLI's error output to one line
        with contextlib.redirect_stderr(io.StringIO()):
            import gymnasium_robotics
    except ImportError:
        return False
    gym.register_envs(gymnasium_robotics)
    return True


def _known_ids_hint(env_id: str) -> str:
    known = sorted(gym.registry)
    close = difflib.get_close_matches(env_id, known, n=3, cutoff=0.6)
    if close:
        return "did you mean " + " or ".join(close)
    return "known ids include digail/FourRooms-v0, digail/CircleWorld-v0, Pendulum-v1 and Hopper-v5"
