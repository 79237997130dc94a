"""Which recipe trains an env's RL expert (its registry entry's `rl_expert`) and where the shipped experts live.

The reasons behind each recipe, with what was measured: docs/experiments.md#rl-experts.
"""

from __future__ import annotations

from pathlib import Path

from digail.config import FINAL_EVAL_SEED as FINAL_EVAL_SEED  # where the experts module has always offered it
from digail.envs.registry import ExpertSpec, env_spec, rl_expert_envs
from digail.errors import UserError

EXPERT_FORMAT = "digail-expert-v1"
WEIGHTS_DIR = Path(__file__).parent / "weights"
FINAL_EVAL_EPISODES = 50
PERIODIC_EVAL_SEED = 5_000


def spec_for(env_id: str) -> ExpertSpec:
    """The recipe of `env_id` (its registry entry's `rl_expert`), or a `UserError` naming the envs that have one."""
    spec = env_spec(env_id)
    if spec is None or spec.rl_expert is None:
        raise UserError(f"no RL expert recipe for {env_id!r}; supported envs are {', '.join(rl_expert_envs())} "
                        "(digail's own envs and Fetch have scripted experts, used by `digail demos`).")
    return spec.rl_expert


def safe_name(env_id: str) -> str:
    """File-system-safe env id (`digail/X-v0` -> `digail-X-v0`)."""
    return env_id.replace("/", "-")


def shipped_expert_path(env_id: str) -> Path:
    """Where the shipped expert of `env_id` lives inside the package."""
    return WEIGHTS_DIR / f"{safe_name(env_id)}.pt"
