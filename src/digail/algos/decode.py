"""Causal decoding of demonstrations: c_t = argmax q(c_t | s_t, c_{t-1}), what the macro-policy does online.

Used by the segmentation metrics, by the VAE polish (q's own segmentation is its target) and by the GAIL trainer
(the expert's codes for the BC term and for replaying code sequences).
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
import torch

from digail.data.trajectory import Trajectory
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
