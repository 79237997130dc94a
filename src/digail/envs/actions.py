"""What an env executes for a sampled action: one rule for the rollouts, the evaluations and the discriminator."""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import gymnasium as gym
import numpy as np


def env_action_fn(env: gym.Env) -> Callable[[Any], Any] | None:
    """The map from a batch of sampled actions (NumPy or torch) to what the env executes (None: as they are).

    Box actions are clipped to their bounds, unless the env defines `canonical_action` (a batch function for
    NumPy and torch), which is then applied instead and must land in the bounds itself: Circle-World executes only
    the direction of an action, and clipping before that would bend the direction whenever a component passes
    +-1, a bias the deterministic policy then carries as a systematic turn. The discriminator sees actions through
    the same map, so it cannot tell agent from expert by a detail the env discards.
    """
    import torch

    space: Any = env.action_space
    if isinstance(space, gym.spaces.Discrete):
        return None
    canonical = getattr(env.unwrapped, "canonical_action", None)
    if canonical is not None:
        def executed(acts: Any) -> Any:
            out = canonical(acts)
            return out if isinstance(out, torch.Tensor) else np.asarray(out, dtype=np.float32)

        return executed
    low, high = space.low.astype(np.float32), space.high.astype(np.float32)
    low_t, high_t = torch.from_numpy(low), torch.from_numpy(high)

    def clipped(acts: Any) -> Any:
        if isinstance(acts, torch.Tensor):
            return torch.max(torch.min(acts, high_t.to(acts.device)), low_t.to(acts.device))
        return np.clip(acts, low, high)

    return clipped
