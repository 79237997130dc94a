"""The on-policy rollout of the trainers: macro-policy codes, sub-task policy actions and the batch arrays.

The vector envs it steps (same-step autoreset; sync, subprocess or envpool) live in `digail.envs.vector`.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from digail.algos.inference import RolloutActorCritic
from digail.envs.vector import VecEnv, VectorEnv

__all__ = ["CodeState", "RolloutState", "VecEnv", "collect_rollout"]


@dataclass
class CodeState:
    """Per-env macro-policy state during rollouts."""

    prev: np.ndarray
    """(N,) previous code, -1 at an episode start (the start input c_{-1})"""
    t_ep: np.ndarray
    """(N,) step index within the current episode"""
    replay_idx: np.ndarray
    """(N,) expert demonstration whose code sequence the env replays (-1: closed loop)"""

    @staticmethod
    def new(n: int) -> CodeState:
        return CodeState(prev=np.full(n, -1, dtype=np.int64), t_ep=np.zeros(n, dtype=np.int64),
                         replay_idx=np.zeros(n, dtype=np.int64))


@dataclass
class RolloutState:
    """Where the next rollout continues: the envs' current normalised observations, codes and episode tallies."""

    obs_n: np.ndarray
    """(N, obs_dim) normalised current observations"""
    codes: np.ndarray
    """(N,) the codes chosen for them"""
    code_state: CodeState
    """the macro-policy's per-env state"""
    ep_returns: np.ndarray
    """(N,) env return of each running episode so far"""
    ep_lengths: np.ndarray
    """(N,) steps of each running episode so far"""


ChooseCodes = Callable[[np.ndarray, np.ndarray, np.ndarray, np.ndarray], tuple[np.ndarray, np.ndarray]]
"""(normalised obs s_t, integer c_{t-1}, step in episode, env indices) -> (c_t, log q(c_t | s_t, c_{t-1}))"""


def collect_rollout(envs: VectorEnv, ac: RolloutActorCritic, state: RolloutState, steps: int,
                    np_rng: np.random.Generator, *,
                    normalize: Callable[[np.ndarray], np.ndarray], choose_codes: ChooseCodes,
                    start_episodes: Callable[[np.ndarray], None], episode_done: Callable[[int], None],
                    env_actions: Callable[[np.ndarray], np.ndarray]) -> dict[str, np.ndarray]:
    """`steps` steps of every env from `state` (advanced in place): the on-policy batch as (T, N, ...) arrays.

    The hot path of training, so it runs in NumPy, where a step costs a few microseconds per array operation
    instead of torch's dispatch per op: `ac` is, on the fast path, a float32 weight snapshot of pi and V
    (`digail.algos.inference.actor_critic`, one forward for both), the action noise is drawn from `np_rng` once,
    and the batch fills preallocated arrays.

    Args:
        envs: the vector env, positioned where `state` says.
        ac: pi and V for the rollout (`digail.algos.inference.actor_critic`).
        state: the envs' current observations and codes, the macro-policy's state and the episode tallies.
        steps: T, steps per env.
        np_rng: the source of the action noise.
        normalize: raw observations -> normalised (the fixed observation normaliser).
        choose_codes: the macro-policy (see `ChooseCodes`); its log q is the directed-info bonus.
        start_episodes: resets the macro-policy state of the envs whose episodes start (indices).
        episode_done: called with an env's index when its episode ends, before the tallies are reset.
        env_actions: sampled actions -> what the envs execute (raising on non-finite ones).

    Returns:
        `obs`, `codes`, `acts`, `logp`, `values`, `bonus` (log q of the code chosen for the state each step
        produced, the final observation where an episode ended), `rews` (env rewards), `final_values` (V of the
        final observation of truncated episodes, for bootstrapping), `terminated`, `truncated`, and `last_values`
        (N,) of the states the rollout ends on.
    """
    T, N, obs_dim = steps, envs.num_envs, state.obs_n.shape[1]
    b_obs = np.empty((T, N, obs_dim), np.float32)
    b_codes = np.empty((T, N), np.int64)
    b_acts = (np.empty((T, N), np.int64) if ac.discrete else np.empty((T, N, ac.act_dim), np.float32))
    b_logp, b_values, b_bonus, b_rews = (np.empty((T, N), np.float32) for _ in range(4))
    b_final_values = np.zeros((T, N), np.float32)
    b_term, b_trunc = np.empty((T, N), bool), np.empty((T, N), bool)
    noise = ac.sample_noise(np_rng, (T, N))
    cstate, all_idx = state.code_state, np.arange(N)
    obs_n, codes, prev = state.obs_n, state.codes, cstate.prev
    for t in range(T):
        acts, b_logp[t], b_values[t] = ac.sample(obs_n, codes, noise[t])
        b_obs[t], b_codes[t], b_acts[t] = obs_n, codes, acts
        next_obs, rews, terms, truncs, _, final = envs.step(env_actions(acts))
        b_rews[t] = rews
        state.ep_returns += rews
        state.ep_lengths += 1
        cstate.t_ep += 1
        next_n = normalize(next_obs)
        if final:
            done = np.fromiter(final, dtype=np.int64, count=len(final))
            final_n = normalize(np.stack([final[i][0] for i in done]))
            # the bonus scores the state the step produced: the final observation where an episode ended
            bonus_obs = next_n.copy()
            bonus_obs[done] = final_n
            codes, b_bonus[t] = choose_codes(bonus_obs, prev, cstate.t_ep, all_idx)
            tr = truncs[done]
            if tr.any():  # a time limit is bootstrapped from V(final obs, its code)
                b_final_values[t, done[tr]] = ac.value(final_n[tr], codes[done[tr]])
            for i in done:
                episode_done(int(i))
                state.ep_returns[i] = 0.0
                state.ep_lengths[i] = 0
            start_episodes(done)  # the start input c_{-1} in prev
            codes[done], _ = choose_codes(next_n[done], prev[done], cstate.t_ep[done], done)
        else:
            codes, b_bonus[t] = choose_codes(next_n, prev, cstate.t_ep, all_idx)
        b_term[t], b_trunc[t] = terms, truncs
        prev[:] = codes
        obs_n = next_n
    state.obs_n, state.codes = obs_n, codes
    return dict(obs=b_obs, codes=b_codes, acts=b_acts, logp=b_logp, values=b_values, bonus=b_bonus, rews=b_rews,
                final_values=b_final_values, terminated=b_term, truncated=b_trunc,
                last_values=ac.value(obs_n, codes))
