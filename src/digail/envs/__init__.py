"""Environments shipped with digail, registered with Gymnasium on `import digail`."""

from __future__ import annotations

import gymnasium as gym


def register_envs() -> None:
    """Register `digail/FourRooms-v0`, `digail/CircleWorld-v0`, `digail/FetchPickAndPlace-v4` (idempotent)."""
    specs = {
        "digail/FourRooms-v0": ("digail.envs.four_rooms:FourRoomsEnv", 64),
        "digail/CircleWorld-v0": ("digail.envs.circle_world:CircleWorldEnv", 120),
        # gymnasium-robotics is imported only when this one is made (digail.envs.fetch)
        "digail/FetchPickAndPlace-v4": ("digail.envs.fetch:FlatFetchPickAndPlace", 50),
    }
    for env_id, (entry_point, steps) in specs.items():
        if env_id not in gym.registry:
            gym.register(id=env_id, entry_point=entry_point, max_episode_steps=steps)
