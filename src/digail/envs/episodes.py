"""The single-environment episode loop every expert rollout, demonstration recording and video uses.

`play_episode` runs one episode of `act(env, obs) -> action` from `env.reset(seed=seed)` and returns an `Episode`;
what else a caller needs it records itself in the `on_step` hook (labels, frames, ...), or asks `keep=True` for
the observations, actions, rewards and infos. (Evaluating a learned policy steps several envs at once so that one
batched network call serves all of them: `digail.eval.returns.run_episodes`.)
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import gymnasium as gym

from digail.envs.registry import tracked_info_keys

Act = Callable[[gym.Env, Any], Any]
"""A policy as the loop calls it: (env, current observation) -> action."""

OnStep = Callable[[gym.Env, Any, Any, float, dict[str, Any]], None]
"""Called after every step with (env, action, next observation, reward, info)."""


@dataclass
class Episode:
    """One played episode."""

    ret: float
    """undiscounted return"""
    length: int
    """steps"""
    reset_info: dict[str, Any]
    """the info of the reset"""
    final_info: dict[str, Any] = field(default_factory=dict)
    """the info of the last step"""
    terminated: bool = False
    """whether it ended by termination (else by truncation)"""
    codes: list[int] = field(default_factory=list)
    """code per step, for hierarchical policies"""
    obs: list[Any] = field(default_factory=list)
    """observations s_0 .. s_T (kept on request)"""
    acts: list[Any] = field(default_factory=list)
    """actions a_0 .. a_{T-1} as passed to the env (kept on request)"""
    rews: list[float] = field(default_factory=list)
    """rewards (kept on request)"""
    infos: list[dict[str, Any]] = field(default_factory=list)
    """infos of the reset and of every step, T + 1 (kept on request)"""
    info_values: dict[str, list[float]] = field(default_factory=dict)
    """per tracked info key (the env's step metrics, `registry.tracked_info_keys`), its value at every step"""

    def add_step(self, reward: float, info: dict[str, Any], track: tuple[str, ...] = ()) -> None:
        """Count one step: its reward into the return, the values of the `track`ed info keys it has."""
        self.ret += float(reward)
        self.length += 1
        for key in track:
            if key in info:
                self.info_values.setdefault(key, []).append(float(info[key]))


def play_episode(env: gym.Env, act: Act, seed: int | None, *, keep: bool = False,
                 on_step: OnStep | None = None) -> Episode:
    """Run one episode from `env.reset(seed=seed)` until it terminates or is truncated."""
    track = tracked_info_keys(env)
    obs, info = env.reset(seed=seed)
    ep = Episode(0.0, 0, info)
    if keep:
        ep.obs.append(obs)
        ep.infos.append(info)
    while True:
        action = act(env, obs)
        obs, reward, terminated, truncated, info = env.step(action)
        ep.add_step(float(reward), info, track)
        if keep:
            ep.obs.append(obs)
            ep.acts.append(action)
            ep.rews.append(float(reward))
            ep.infos.append(info)
        if on_step is not None:
            on_step(env, action, obs, float(reward), info)
        if terminated or truncated:
            ep.final_info, ep.terminated = info, bool(terminated)
            return ep


def play_episodes(env: gym.Env, act: Act, episodes: int, seed: int, *, keep: bool = False,
                  on_step: OnStep | None = None, on_episode: Callable[[Episode], None] | None = None
                  ) -> list[Episode]:
    """`episodes` episodes, episode i reset with seed `seed + i`; `on_episode` sees each as it ends."""
    out = []
    for i in range(episodes):
        ep = play_episode(env, act, seed + i, keep=keep, on_step=on_step)
        if on_episode is not None:
            on_episode(ep)
        out.append(ep)
    return out
