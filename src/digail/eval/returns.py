"""Roll out a hierarchical policy for N episodes and score it: returns, task metrics, normalised return.

Evaluation is always closed-loop: the macro-policy q picks c_t = argmax q(. | s_t, c_{t-1}) from the agent's own
states, exactly what segmentation does offline. `digail compose` swaps q for a user's code schedule.
"""

from __future__ import annotations

import contextlib
import hashlib
import json
import os
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from digail.algos.decode import hierarchical_act
from digail.config import FINAL_EVAL_SEED
from digail.envs import make_env
from digail.envs.actions import env_action_fn
from digail.envs.episodes import Episode, play_batch, play_episodes
from digail.envs.registry import env_spec
from digail.errors import UserError
from digail.experts import expert_for
from digail.fsio import write_json
from digail.nets.vae import HierarchicalPolicy
from digail.version import __version__

# Final-info keys an env may report, and how eval.json names their aggregate.
RATE_KEYS = {"is_success": "success_rate", "order_correct": "order_correct_rate",
             "order_reversed": "order_reversed_rate"}
MEAN_KEYS = ("radius_error", "closure_error")


def run_episodes(model: HierarchicalPolicy, env_id: str, episodes: int, seed: int, *, deterministic: bool = False,
                 schedule: Sequence[int] | None = None, num_envs: int = 8, keep_obs: int = 0,
                 env_kwargs: dict[str, Any] | None = None) -> list[Episode]:
    """Run `episodes` episodes (episode e reset with seed + e) with the model's sub-task policies, on up to
    `num_envs` envs at once (`play_batch`).

    Codes come from the closed-loop macro-policy (argmax of q), or from `schedule` (code per step; the last code
    repeats once it runs out). The first `keep_obs` episodes keep their observations for plots.
    """
    envs = [make_env(env_id, **(env_kwargs or {})) for _ in range(max(min(num_envs, episodes), 1))]
    try:
        act = hierarchical_act(model, env_action_fn(envs[0]), deterministic=deterministic, schedule=schedule)
        return play_batch(envs, act, episodes, seed, keep=keep_obs)
    finally:
        for env in envs:
            env.close()


def task_metrics(episodes: list[Episode], env_id: str | None = None) -> dict[str, float]:
    """Env-specific scores from the episodes' infos (success, path-length ratio, circle drawing) and the step
    metrics `env_id`'s registry entry declares (e.g. Fetch's dense return and grasp rate)."""
    out: dict[str, float] = {}
    spec = env_spec(env_id or "")
    for metric in spec.step_metrics if spec is not None else ():
        per_episode = [e.info_values.get(metric.info_key, []) for e in episodes]
        if not any(per_episode):
            continue
        scores = [float(np.sum(v)) if metric.reduce == "sum" else float(np.any(np.asarray(v) > 0))
                  for v in per_episode]
        out[metric.name] = float(np.mean(scores))
    finals = [e.final_info for e in episodes]
    for key, name in RATE_KEYS.items():
        vals = [bool(f[key]) for f in finals if key in f]
        if vals:
            out[name] = float(np.mean(vals))
    for key in MEAN_KEYS:
        nums = [float(f[key]) for f in finals if key in f]
        if nums:
            # capped at 1 per episode: a half drawn as a straight line scores inf and would swamp the mean
            out[key] = float(np.mean(np.minimum(nums, 1.0)))
            out[f"{key}_median"] = float(np.median(nums))
    ratios = [e.length / e.reset_info["shortest_path_length"] for e in episodes
              if e.final_info.get("is_success") and e.reset_info.get("shortest_path_length")]
    if any("shortest_path_length" in e.reset_info for e in episodes):
        out["path_length_ratio"] = float(np.mean(ratios)) if ratios else float("nan")
    return out


def episode_returns(episodes: list[Episode], env_id: str | None = None) -> np.ndarray:
    """Per-episode returns as evaluation reports them: the env reward's, or the step metric the registry entry
    names in `eval_return` (Fetch: the dense return of the paper's Table 2)."""
    spec = env_spec(env_id or "")
    if spec is None or spec.eval_return is None:
        return np.array([e.ret for e in episodes])
    metric = next(m for m in spec.step_metrics if m.name == spec.eval_return)
    return np.array([float(np.sum(e.info_values.get(metric.info_key, []))) for e in episodes])


def summarize(episodes: list[Episode], env_id: str | None = None) -> dict[str, Any]:
    """Mean and std of returns (see `episode_returns`), mean length and the task metrics of `env_id`."""
    rets = episode_returns(episodes, env_id)
    out = {"episodes": len(episodes), "mean_return": float(rets.mean()), "std_return": float(rets.std()),
           "mean_length": float(np.mean([e.length for e in episodes]))}
    spec = env_spec(env_id or "")
    if spec is not None and spec.eval_return is not None:
        out[spec.reward_name] = float(np.mean([e.ret for e in episodes]))
    return {**out, **task_metrics(episodes, env_id)}


def expert_cache_file() -> Path:
    """Where measured expert returns are kept: `$DIGAIL_CACHE_DIR`, else `$XDG_CACHE_HOME/digail`, else
    `~/.cache/digail`, in `expert_returns.json`."""
    root = os.environ.get("DIGAIL_CACHE_DIR") or str(
        Path(os.environ.get("XDG_CACHE_HOME") or Path.home() / ".cache") / "digail")
    return Path(root) / "expert_returns.json"


def _expert_key(env_id: str, kind: str, episodes: int, seed: int) -> str:
    """What a measurement depends on: env, episodes, seeds, the expert (its weights' hash for an RL expert) and the
    digail version (which fixes the envs and the scripted experts)."""
    weights = ""
    if kind == "rl":
        from digail.experts.rl import shipped_expert_path

        path = shipped_expert_path(env_id)
        weights = hashlib.sha256(path.read_bytes()).hexdigest()[:16] if path.is_file() else "missing"
    spec = env_spec(env_id)
    measure = f"|return={spec.eval_return}" if spec is not None and spec.eval_return else ""
    return (f"{env_id}|episodes={episodes}|seed={seed}|{kind}{':' + weights if weights else ''}|{__version__}"
            f"{measure}")


def expert_summary(env_id: str, episodes: int, seed: int) -> dict[str, Any] | None:
    """The expert measured the same way as the agent: same env, seeds and episode count (None: no expert).

    Measured once per (env, episodes, seed, expert) and kept in `expert_cache_file()`: the expert is deterministic
    on seeded episodes, so every later evaluation reads the same numbers instead of playing them again.
    """
    try:
        policy, kind = expert_for(env_id)
    except (UserError, OSError):  # no expert for this env: nothing to normalise by
        return None
    cache = expert_cache_file()
    key = _expert_key(env_id, kind, episodes, seed)
    try:
        known = json.loads(cache.read_text()) if cache.is_file() else {}
    except (OSError, ValueError):  # an unreadable cache is measured again and rewritten
        known = {}
    if isinstance(known, dict) and isinstance(known.get(key), dict):
        return dict(known[key])
    env = make_env(env_id)
    eps = play_episodes(env, policy, episodes, seed)
    env.close()
    result = summarize(eps, env_id)
    try:
        fresh = json.loads(cache.read_text()) if cache.is_file() else {}
        fresh = fresh if isinstance(fresh, dict) else {}
    except (OSError, ValueError):
        fresh = {}
    fresh[key] = result
    with contextlib.suppress(OSError):  # a read-only home only costs the next evaluation a re-measurement
        write_json(cache, fresh)
    return result


def evaluate(model: HierarchicalPolicy, env_id: str, episodes: int = 300, seed: int = FINAL_EVAL_SEED,
             deterministic: bool = True, with_expert: bool = True,
             env_kwargs: dict[str, Any] | None = None) -> dict[str, Any]:
    """Closed-loop evaluation; adds `normalized_return` (agent / expert mean return) when an expert exists (not
    with `env_kwargs`: the expert is measured on the env's default task)."""
    eps = run_episodes(model, env_id, episodes, seed, deterministic=deterministic, env_kwargs=env_kwargs)
    out = summarize(eps, env_id)
    out.update(env_id=env_id, seed=seed, deterministic=deterministic, macro_policy="closed-loop argmax q")
    if env_kwargs:
        out["env_kwargs"] = env_kwargs
    if with_expert and not env_kwargs:
        expert = expert_summary(env_id, episodes, seed)
        if expert is not None:
            out["expert"] = expert
            denom = expert["mean_return"]
            # agent / expert; undefined where the expert's return is ~0 (Circle-World's reward is minus the
            # distance to the expert's own path, so the expert scores 0 and the task metrics say more)
            out["normalized_return"] = float(out["mean_return"] / denom) if abs(denom) > 1e-6 else None
    return out
