"""The one episode loop: every expert rollout, demonstration recording, evaluation and video plays through it.

`play_batch` runs episodes on one or several envs at once, each env reset with the next episode's seed as soon as
its episode ends, so that one batched network call serves all of them; `play_episode` / `play_episodes` are its
single-env form for `act(env, obs) -> action` policies (the experts). What else a caller needs it records in the
hooks (`on_step`, `on_episode`; codes, frames, ...), or asks `keep` for the observations, actions, rewards and
infos.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import Any

import gymnasium as gym

from digail.envs.registry import tracked_info_keys

Act = Callable[[gym.Env, Any], Any]
"""A policy as the loop calls it: (env, current observation) -> action."""

BatchAct = Callable[[list[gym.Env], list[Any], list["Episode"]], Sequence[Any]]
"""A policy acting in several envs at once: (the envs, their current observations, their episodes so far) -> one
action per env. A hierarchical policy notes the code it picks in each `Episode.codes`."""

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


def play_batch(envs: Sequence[gym.Env], act: BatchAct, episodes: int, seed: int | None, *, keep: int = 0,
               on_step: OnStep | None = None, on_episode: Callable[[Episode], None] | None = None
               ) -> list[Episode]:
    """Play `episodes` episodes (episode i reset with `seed + i`, or unseeded) on `envs`, in episode order.

    The envs start episodes 0 .. len(envs) - 1; each step calls `act` once for every env with an unfinished
    episode and steps those envs in order; an env whose episode ends takes the next unplayed one. With one env this
    is the plain episode-after-episode loop. The first `keep` episodes keep their observations, actions, rewards and
    infos; `on_step` sees every step, `on_episode` each episode as it ends (before its env is reset again).
    """
    envs = list(envs)[:max(episodes, 0)]
    track = tracked_info_keys(envs[0]) if envs else ()
    results: list[Episode | None] = [None] * max(episodes, 0)
    index = list(range(len(envs)))  # the episode each env plays
    current: list[Episode] = []
    obs: list[Any] = []

    def start(ep: int, env: gym.Env) -> tuple[Any, Episode]:
        first, info = env.reset(seed=None if seed is None else seed + ep)
        rec = Episode(0.0, 0, info)
        if ep < keep:
            rec.obs.append(first)
            rec.infos.append(info)
        return first, rec

    for ep, env in enumerate(envs):
        o, rec = start(ep, env)
        obs.append(o)
        current.append(rec)
    next_ep = len(envs)
    while envs:
        actions = act(envs, obs, current)
        running = []
        for k, (env, action) in enumerate(zip(envs, actions, strict=True)):
            ep, rec = index[k], current[k]
            o, reward, terminated, truncated, info = env.step(action)
            rec.add_step(float(reward), info, track)
            if ep < keep:
                rec.obs.append(o)
                rec.acts.append(action)
                rec.rews.append(float(reward))
                rec.infos.append(info)
            if on_step is not None:
                on_step(env, action, o, float(reward), info)
            if terminated or truncated:
                rec.final_info, rec.terminated = info, bool(terminated)
                results[ep] = rec
                if on_episode is not None:
                    on_episode(rec)
                if next_ep >= episodes:
                    continue  # this env has no episode left to play
                ep, next_ep = next_ep, next_ep + 1
                o, rec = start(ep, env)
            running.append((env, ep, o, rec))
        envs = [r[0] for r in running]
        index = [r[1] for r in running]
        obs = [r[2] for r in running]
        current = [r[3] for r in running]
    return [r for r in results if r is not None]


def _single(act: Act) -> BatchAct:
    """A one-env policy `act(env, obs)` as the batched loop calls it."""
    return lambda envs, obs, eps: [act(envs[0], obs[0])]


def play_episode(env: gym.Env, act: Act, seed: int | None, *, keep: bool = False,
                 on_step: OnStep | None = None) -> Episode:
    """Run one episode from `env.reset(seed=seed)` until it terminates or is truncated."""
    return play_batch([env], _single(act), 1, seed, keep=int(keep), on_step=on_step)[0]


def play_episodes(env: gym.Env, act: Act, episodes: int, seed: int, *, keep: bool = False,
                  on_step: OnStep | None = None, on_episode: Callable[[Episode], None] | None = None
                  ) -> list[Episode]:
    """`episodes` episodes, episode i reset with seed `seed + i`; `on_episode` sees each as it ends."""
    return play_batch([env], _single(act), episodes, seed, keep=episodes if keep else 0, on_step=on_step,
                      on_episode=on_episode)
