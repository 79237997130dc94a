"""Observation normalisation fitted on the expert demonstrations and saved in every checkpoint."""

from __future__ import annotations

from collections.abc import Callable

import numpy as np
import torch
from torch import nn


class ObsNormalizer(nn.Module):
    """`(obs - mean) / std`, clipped to +-10. The statistics are buffers, so they travel in the state_dict."""

    mean: torch.Tensor
    std: torch.Tensor

    def __init__(self, obs_dim: int, clip: float = 10.0) -> None:
        super().__init__()
        self.clip = clip
        self.register_buffer("mean", torch.zeros(obs_dim))
        self.register_buffer("std", torch.ones(obs_dim))

    @torch.no_grad()
    def fit(self, obs: np.ndarray, min_std: float = 1e-3) -> ObsNormalizer:
        """Set the statistics from an (N, obs_dim) array; near-constant features keep a floor std."""
        obs = np.asarray(obs, dtype=np.float64).reshape(len(obs), -1)
        self.mean.copy_(torch.as_tensor(obs.mean(0), dtype=torch.float32))
        self.std.copy_(torch.as_tensor(np.maximum(obs.std(0), min_std), dtype=torch.float32))
        return self

    def forward(self, obs: torch.Tensor) -> torch.Tensor:
        return ((obs - self.mean) / self.std).clamp(-self.clip, self.clip)

    def numpy_fn(self) -> Callable[[np.ndarray], np.ndarray]:
        """`forward` in NumPy, op for op, with the current statistics: the rollouts' hot path normalises without
        torch's per-op dispatch. The returned function works in place on the array `obs - mean` it makes."""
        mean, std, clip = self.mean.cpu().numpy(), self.std.cpu().numpy(), float(self.clip)

        def normalize(obs: np.ndarray) -> np.ndarray:
            x = obs - mean
            x /= std
            np.maximum(x, -clip, out=x)
            return np.minimum(x, clip, out=x)

        return normalize
