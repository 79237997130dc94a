"""The off-policy learner's replay buffer: transitions in preallocated NumPy arrays, checkpointed as tensors."""

from __future__ import annotations

from typing import Any

import numpy as np
import torch

from digail.errors import UserError

FIELDS = ("obs", "codes", "acts", "next_obs", "next_codes", "terminated", "bonus", "rews")
"""what every stored transition holds (see `ReplayBuffer`)"""


class ReplayBuffer:
    """A ring of the last `capacity` transitions (s_t, c_t, a_t, s_{t+1}, c_{t+1}, terminated, bonus, env reward).

    `obs` / `next_obs` are normalised observations (the normaliser is fixed during training), `acts` the executed
    actions (what D and the critics see), `next_obs` the final observation where an episode ended, `next_codes`
    the code the macro-policy chose for s_{t+1} during the rollout (the one the bootstrap target uses),
    `terminated` true only for an end by termination (a time limit is bootstrapped), `bonus` the directed-info
    bonus log q(c_{t+1} | s_{t+1}, c_t) of the transition (q is frozen, so it is stored once) and `rews` the env's
    reward (logged, and the reward of runs on the env's own reward). D's reward is not stored: it is relabelled
    with the current D on every sampled batch.
    """

    def __init__(self, capacity: int, obs_dim: int, act_shape: tuple[int, ...], act_dtype: Any) -> None:
        self.capacity = capacity
        self.obs = np.zeros((capacity, obs_dim), np.float32)
        self.codes = np.zeros(capacity, np.int64)
        self.acts = np.zeros((capacity, *act_shape), act_dtype)
        self.next_obs = np.zeros((capacity, obs_dim), np.float32)
        self.next_codes = np.zeros(capacity, np.int64)
        self.terminated = np.zeros(capacity, bool)
        self.bonus = np.zeros(capacity, np.float32)
        self.rews = np.zeros(capacity, np.float32)
        self.pos = 0
        """where the next transition goes"""
        self.size = 0
        """transitions held"""

    def add(self, **batch: np.ndarray) -> None:
        """Store a batch of N transitions (one per env), each field an array with N rows."""
        n = len(batch["obs"])
        idx = (self.pos + np.arange(n)) % self.capacity
        for name in FIELDS:
            getattr(self, name)[idx] = batch[name]
        self.pos = int((self.pos + n) % self.capacity)
        self.size = min(self.size + n, self.capacity)

    def sample_indices(self, n: int, gen: torch.Generator) -> np.ndarray:
        """`n` indices drawn uniformly with replacement from the held transitions (from the torch generator, so
        that a resumed run draws the same)."""
        return torch.randint(self.size, (n,), generator=gen).numpy()

    def get(self, idx: np.ndarray, device: torch.device) -> dict[str, torch.Tensor]:
        """The transitions at `idx` as tensors on `device`."""
        return {name: torch.from_numpy(getattr(self, name)[idx]).to(device) for name in FIELDS}

    def state_dict(self) -> dict[str, Any]:
        """The held transitions as tensors (weights_only-loadable), in storage order, with the write position."""
        n = self.size
        return {"pos": self.pos, "size": n, "capacity": self.capacity,
                **{name: torch.from_numpy(getattr(self, name)[:n].copy()) for name in FIELDS}}

    def load_state_dict(self, state: dict[str, Any]) -> None:
        n, pos = int(state["size"]), int(state["pos"])
        if int(state["capacity"]) != self.capacity or not 0 <= pos < max(self.capacity, 1) or n > self.capacity:
            raise UserError(f"the checkpoint's replay buffer holds {state['capacity']} transitions, this run's "
                            f"{self.capacity}; resume with the run's own settings.")
        for name in FIELDS:
            arr = state[name].numpy()
            dest = getattr(self, name)
            if arr.shape[1:] != dest.shape[1:] or len(arr) != n:
                raise UserError("the checkpoint's replay buffer does not fit this model's observations or actions; "
                                "resume with the run's own settings.")
            dest[:n] = arr
        self.pos, self.size = pos, n
