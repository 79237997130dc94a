"""Gymnasium registration of digail's environments and `make_env`, the one way the package creates an env."""

from __future__ import annotations

import contextlib
import difflib
import io
from typing import Any

import gymnasium as gym

from digail.errors import UserError
from digail.utils import one_line


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


def make_env(env_id: str, **kwargs: Any) -> gym.Env:
    """`gym.make(env_id, **kwargs)` that reports an unknown or unavailable id as one `UserError` sentence.

    digail's own envs are registered by importing `digail`; robotics ids (e.g. FetchPickAndPlace-v4) are
    registered on demand by importing `gymnasium_robotics` when it is installed.
    """
    register_envs()
    for attempt in range(2):
        try:
            return gym.make(env_id, **kwargs)
        except (gym.error.NameNotFound, gym.error.NamespaceNotFound, gym.error.VersionNotFound) as exc:
            if attempt == 0 and _register_robotics():
                continue
            raise UserError(f"unknown environment id {env_id!r}; {_known_ids_hint(env_id)}.") from exc
        except gym.error.DependencyNotInstalled as exc:
            first = str(exc).strip().splitlines()[0] if str(exc).strip() else type(exc).__name__
            raise UserError(f"environment {env_id!r} needs a package that is not installed ({first}).") \
                from exc
        except gym.error.Error as exc:
            raise UserError(f"could not create environment {env_id!r}: {one_line(exc)}.") from exc
    raise AssertionError("unreachable")


def _register_robotics() -> bool:
    try:
        # its import prints a version notice to stderr; keep the CLI's error output to one line
        with contextlib.redirect_stderr(io.StringIO()):
            import gymnasium_robotics
    except ImportError:
        return False
    gym.register_envs(gymnasium_robotics)
    return True


def _known_ids_hint(env_id: str) -> str:
    known = sorted(gym.registry)
    close = difflib.get_close_matches(env_id, known, n=3, cutoff=0.6)
    if close:
        return "did you mean " + " or ".join(close)
    return "known ids include digail/FourRooms-v0, digail/CircleWorld-v0, Pendulum-v1 and Hopper-v5"
