"""Which recipe trains an env's RL expert (`RECIPES`) and where the shipped experts live.

The reasons behind each recipe, with what was measured: docs/experiments.md#rl-experts.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from digail.config import FINAL_EVAL_SEED as FINAL_EVAL_SEED  # where the experts module has always offered it
from digail.errors import UserError

EXPERT_FORMAT = "digail-expert-v1"
WEIGHTS_DIR = Path(__file__).parent / "weights"
FINAL_EVAL_EPISODES = 50
PERIODIC_EVAL_SEED = 5_000



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

RECIPES: dict[str, ExpertSpec] = {
    # SAC as in the RL-Zoo's entry (learning rate 1e-3, SB3's other defaults); the replay buffer holds the
    # whole budget; 64x64 nets keep one gradient step per env step affordable on a CPU
    "Pendulum-v1": ExpertSpec(
        algo="sac", steps=20_000, target=-150.0, n_envs=1, net_arch=(64, 64), activation="relu",
        sac={"learning_rate": 1e-3, "buffer_size": 200_000},
        checkpoint_every=5_000, eval_every=2_500, eval_episodes=50, stop_at=None),
    # balancing is easy: plain PPO with small nets
    "InvertedPendulum-v5": ExpertSpec(
        steps=300_000, target=1000.0, n_envs=8,
        ppo={"n_steps": 256, "batch_size": 64, "n_epochs": 10, "learning_rate": 3e-4, "gae_lambda": 0.95,
             "clip_range": 0.2, "ent_coef": 0.0},
        checkpoint_every=20_000, eval_every=20_000, eval_episodes=20, stop_at=1000.0),
    "Hopper-v5": ExpertSpec(
        steps=3_000_000, target=3000.0, ppo=_LOCOMOTION_PPO, net_arch=(256, 256), log_std_init=-0.5,
        checkpoint_every=100_000, eval_every=100_000, stop_at=3300.0),
    "Walker2d-v5": ExpertSpec(
        steps=5_000_000, target=4000.0, ppo=_LOCOMOTION_PPO, net_arch=(256, 256), log_std_init=-0.5,
        checkpoint_every=100_000, eval_every=100_000, stop_at=4400.0),
}
"""env id -> how `digail expert` trains its RL expert"""


def rl_expert_envs() -> list[str]:
    """The envs with an RL expert recipe."""
    return list(RECIPES)


def spec_for(env_id: str) -> ExpertSpec:
    """The recipe of `env_id`, or a `UserError` naming the envs that have one."""
    spec = RECIPES.get(env_id)
    if spec is None:
        raise UserError(f"no RL expert recipe for {env_id!r}; supported envs are {', '.join(rl_expert_envs())} "
                        "(digail's own envs and Fetch have scripted experts, used by `digail demos`).")
    return spec


def safe_name(env_id: str) -> str:
    """File-system-safe env id (`digail/X-v0` -> `digail-X-v0`)."""
    return env_id.replace("/", "-")


def shipped_expert_path(env_id: str) -> Path:
    """Where the shipped expert of `env_id` lives inside the package."""
    return WEIGHTS_DIR / f"{safe_name(env_id)}.pt"
