"""The expert's side of the trainer: the demonstrations as tensors for D and the BC term, and q's codes of them."""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass

import numpy as np
import torch

from digail.algos.decode import segment_many
from digail.data.trajectory import Trajectory
from digail.nets.vae import HierarchicalPolicy


@dataclass(frozen=True)
class ExpertData:
    """Every demonstration step s_t -> a_t, flattened over the demonstrations (M steps in all)."""

    obs_n: torch.Tensor
    """(M, obs_dim) normalised observations"""
    acts: torch.Tensor
    """(M,) int64 (discrete) or (M, act_dim) float32 actions, as recorded"""
    disc_in: torch.Tensor
    """(M, obs_dim + D's action size) D's input: the observations beside the actions as D sees them"""
    codes: torch.Tensor
    """(M,) int64 q's causal code of each step (`segment_many`), the c_E of the BC term"""
    replay_codes: np.ndarray
    """(demonstrations, longest) q's code sequence of each demonstration, -1 past its end (expert-replay rollouts)"""


def expert_data(model: HierarchicalPolicy, demos: Sequence[Trajectory], act_input: Callable[[torch.Tensor],
                torch.Tensor], *, discrete: bool, device: torch.device) -> ExpertData:
    """The demonstrations through the model's (fixed) normaliser and q, and `act_input` (actions as D sees them)."""
    obs_n, acts, disc_in = disc_rows(model, np.concatenate([np.asarray(t.obs[:-1], np.float32) for t in demos]),
                                     np.concatenate([np.asarray(t.acts) for t in demos]), act_input,
                                     discrete=discrete, device=device)
    seqs = segment_many(model, demos)
    codes = torch.as_tensor(np.concatenate(seqs), dtype=torch.long, device=device)
    replay_codes = np.full((len(seqs), max(len(s) for s in seqs)), -1, dtype=np.int64)
    for i, s in enumerate(seqs):
        replay_codes[i, : len(s)] = s
    return ExpertData(obs_n=obs_n, acts=acts, disc_in=disc_in, codes=codes, replay_codes=replay_codes)


def disc_rows(model: HierarchicalPolicy, obs: np.ndarray, acts_np: np.ndarray,
              act_input: Callable[[torch.Tensor], torch.Tensor], *, discrete: bool,
              device: torch.device) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """Recorded (obs, action) rows -> (normalised obs, actions as tensors, their D input [obs_n, act_input])."""
    obs_n = model.normalizer(torch.as_tensor(obs, dtype=torch.float32, device=device))
    acts = torch.as_tensor(acts_np, dtype=torch.long if discrete else torch.float32, device=device)
    return obs_n, acts, torch.cat([obs_n, act_input(acts)], -1)


def relabelled_goals(demos: Sequence[Trajectory], goal: slice, achieved: slice, copies: int,
                     rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    """`copies` relabelled copies of every demonstration step (s_t, a_t): the goal columns of s_t replaced by the
    achieved columns of s_t' for t' drawn uniformly from t + 1 .. T of the same demonstration (HER's "future"
    goals), so the action still heads for a place the expert went on to reach. Returns (obs, acts): demonstration
    by demonstration, its copies one after another."""
    obs_out, acts_out = [], []
    for t in demos:
        obs = np.asarray(t.obs, np.float32)
        steps = len(obs) - 1
        later = rng.integers(np.arange(1, steps + 1), steps + 1, size=(copies, steps))  # (copies, T): t' > t
        rows = np.repeat(obs[None, :-1], copies, axis=0)
        rows[..., goal] = obs[later, achieved]
        obs_out.append(rows.reshape(copies * steps, -1))
        acts = np.asarray(t.acts)
        acts_out.append(np.repeat(acts[None], copies, axis=0).reshape(copies * steps, *acts.shape[1:]))
    return np.concatenate(obs_out), np.concatenate(acts_out)
