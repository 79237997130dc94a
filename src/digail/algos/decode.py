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
