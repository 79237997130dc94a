"""Causal decoding: c_t = argmax q(c_t | s_t, c_{t-1}), offline on demonstrations and online as the macro-policy.

`segment_many` serves the segmentation metrics, the VAE polish (q's own segmentation is its target) and the GAIL
trainer (the expert's codes for the BC term and for replaying code sequences); `hierarchical_act` is the same rule
acting in envs, for evaluation, composition and videos.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from typing import Any

import numpy as np
import torch

from digail.data.trajectory import Trajectory
from digail.envs.episodes import BatchAct, Episode
from digail.errors import UserError
from digail.nets.mlp import one_hot
from digail.nets.vae import HierarchicalPolicy


def padded_obs(model: HierarchicalPolicy, trajs: Sequence[Trajectory]) -> tuple[torch.Tensor, np.ndarray]:
    """(B, T_max, obs_dim) normalised observations s_0 .. s_{T-1} and the lengths T."""
    lengths = np.array([len(t) for t in trajs])
    obs = np.zeros((len(trajs), lengths.max(), model.obs_dim), np.float32)
    for i, t in enumerate(trajs):
        if int(np.prod(np.shape(t.obs)[1:])) != model.obs_dim:
            raise UserError(f"the demonstrations have observations of shape {np.shape(t.obs)[1:]} but the model "
                            f"expects {model.obs_dim} numbers; segment demonstrations of the model's environment.")
        obs[i, :len(t)] = np.asarray(t.obs[:len(t)], np.float32).reshape(len(t), -1)
    device = next(model.parameters()).device
    with torch.no_grad():
        obs_n = model.normalizer(torch.as_tensor(obs, device=device))
    return obs_n, lengths


@torch.no_grad()
def segment_many(model: HierarchicalPolicy, trajs: Sequence[Trajectory]) -> list[np.ndarray]:
    """Causal codes for many demonstrations at once (batched over demonstrations, one loop over time).

    Returns:
        One (T_i,) int64 array per demonstration: c_t for the states s_0 .. s_{T_i - 1}.
    """
    if len(trajs) == 0:
        return []
    if model.codes == 1:
        return [np.zeros(len(t), dtype=np.int64) for t in trajs]
    obs_n, lengths = padded_obs(model, trajs)
    B, T, _ = obs_n.shape
    codes = torch.empty(B, T, dtype=torch.int64, device=obs_n.device)
    prev = torch.zeros(B, model.codes, device=obs_n.device)
    for t in range(T):
        c = model.next_code(obs_n[:, t], prev)
        codes[:, t] = c
        prev = one_hot(c, model.codes)
    out = codes.cpu().numpy()
    return [out[i, :n].copy() for i, n in enumerate(lengths)]


def segment(model: HierarchicalPolicy, traj: Trajectory) -> np.ndarray:
    """Causal codes c_t = argmax q(. | s_t, c_{t-1}) of one demonstration: a (T,) int64 array."""
    return segment_many(model, [traj])[0]


def hierarchical_act(model: HierarchicalPolicy, to_env: Callable[[Any], Any] | None, *, deterministic: bool = True,
                     schedule: Sequence[int] | None = None) -> BatchAct:
    """The model as a policy for `digail.envs.episodes.play_batch`: per env, the code c_t (argmax q given the
    episode's previous code, or `schedule[t]`, whose last code repeats once it runs out), noted in the episode's
    `codes`, then pi's action (its mode when `deterministic`, else a sample) through `to_env` (see
    `digail.envs.actions.env_action_fn`; None: as sampled)."""
    model.eval()
    device = next(model.parameters()).device
    K = model.codes
    eye = torch.eye(K, device=device)

    @torch.no_grad()
    def act(envs: list[Any], obs: list[Any], eps: list[Episode]) -> Any:
        obs_n = model.normalizer(torch.as_tensor(np.stack([np.asarray(o, np.float32) for o in obs]), device=device))
        if schedule is not None:
            codes = torch.as_tensor([schedule[min(e.length, len(schedule) - 1)] for e in eps], device=device)
        else:
            prev = torch.as_tensor([e.codes[-1] if e.codes else -1 for e in eps], device=device)
            codes = model.q(obs_n, one_hot(prev, K)).argmax(-1)
        for e, c in zip(eps, codes.tolist(), strict=True):
            e.codes.append(int(c))
        code_1h = eye[codes]
        acts = model.pi.mode(obs_n, code_1h) if deterministic else model.pi.dist(obs_n, code_1h).sample()
        acts_np = acts.cpu().numpy()
        return to_env(acts_np) if to_env is not None else acts_np

    return act


READINGS = ("causal", "offline")
"""the two readings of a segmentation (`read_codes`): `causal`, what the macro-policy q decides step by step without
looking ahead (the paper's q, what the hierarchical policy does in closed loop); `offline`, the code path that best
explains the whole demonstration, actions included (`segment_offline_many`), for annotations and generation"""


@torch.no_grad()
def segment_offline_many(model: HierarchicalPolicy, trajs: Sequence[Trajectory]) -> list[np.ndarray]:
    """The offline reading: per demonstration, the code path maximising
    sum_t log q(c_t | s_t, c_{t-1}) + log pi(a_t | s_t, c_t) (Viterbi; c_{-1} the start input), the most likely codes
    under the hierarchical policy's own model of the actions given the states.

    Why beside the causal reading: q decides c_t from s_t alone and cannot see that the next actions belong to
    another sub-task, so its switches come late or flicker where two sub-tasks look alike; the offline reading
    also weighs every action the sub-task policies would have taken, before and after. An annotation is written
    after the fact, so it may use the whole demonstration.

    Returns:
        One (T_i,) int64 array per demonstration: c_t for the states s_0 .. s_{T_i - 1}.
    """
    from digail.algos.segment_search import _viterbi_trans

    if len(trajs) == 0:
        return []
    K = model.codes
    if K == 1:
        return [np.zeros(len(t), dtype=np.int64) for t in trajs]
    obs_n, lengths = padded_obs(model, trajs)
    B, T, _ = obs_n.shape
    device = obs_n.device
    acts = np.zeros((B, T), np.int64) if model.action.discrete else np.zeros((B, T, model.action.dim), np.float32)
    for i, t in enumerate(trajs):
        acts[i, :len(t)] = np.asarray(t.acts).reshape(acts[i, :len(t)].shape)
    acts_t = torch.as_tensor(acts, device=device)
    eye = torch.eye(K, device=device)
    loglik = torch.zeros(B, T, K, device=device)
    logtrans = torch.zeros(B, T, K, K, device=device)
    for k in range(K):
        code = eye[k].expand(B, T, K)
        loglik[..., k] = model.pi.log_prob_entropy_of(model.pi.inputs(obs_n, code), acts_t)[0]
        logtrans[:, :, k] = torch.log_softmax(model.q(obs_n, code), -1)
    start = torch.log_softmax(model.q(obs_n[:, 0], torch.zeros(B, K, device=device)), -1)
    loglik[:, 0] += start
    mask = torch.as_tensor(np.arange(T)[None] < lengths[:, None], device=device)
    loglik = loglik * mask[..., None]
    logtrans = logtrans * mask[..., None, None]
    return _viterbi_trans(loglik.double().cpu().numpy(), logtrans.double().cpu().numpy(), lengths)


def read_codes(model: HierarchicalPolicy, trajs: Sequence[Trajectory], reading: str = "offline"
               ) -> list[np.ndarray]:
    """The codes of `trajs` in one of the `READINGS`."""
    if reading not in READINGS:
        raise UserError(f"unknown reading {reading!r}; choose one of {', '.join(READINGS)}.")
    return segment_offline_many(model, trajs) if reading == "offline" else segment_many(model, trajs)
