"""Environments defined outside digail: named on the command line as `module:EnvId`, or found through the entry
point a Minari dataset recorded.

`--env shuttle_env:Shuttle-v0` imports `shuttle_env` (from the current folder or `PYTHONPATH`), whose import
registers `Shuttle-v0` with Gymnasium, and then stands for `Shuttle-v0` everywhere (run folders, datasets and
checks name the env by its id alone). A dataset recorded in an env that is not registered here carries the env's
entry point (`shuttle_env:Shuttle`): reading the dataset registers the id with it, so the env is made once its
module can be imported.
"""

from __future__ import annotations

import contextlib
import importlib
import importlib.util
import os
import sys
from collections.abc import Callable
from typing import Any

import gymnasium as gym

from digail.errors import UserError


def import_env_module(env_id: str) -> str:
    """`env_id` without its `module:` part, once that module is imported (which registers the env).

    The current folder is searched too, as `python -m` would: a user's env module usually sits beside the data.

    Raises:
        UserError: when the module cannot be imported, naming it and the fix.
    """
    module, sep, name = env_id.partition(":")
    if not sep:
        return env_id
    if not module or not name:
        raise UserError(f"environment {env_id!r} is not of the form module:EnvId (e.g. shuttle_env:Shuttle-v0).")
    _search_current_folder()
    try:
        importlib.import_module(module)
    except ImportError as exc:
        why = str(exc).strip().splitlines()[0] if str(exc).strip() else type(exc).__name__
        raise UserError(f"cannot import module {module!r} named in {env_id!r} ({why}); run from the "
                        "folder that holds it or add that folder to PYTHONPATH.") from exc
    return name


def import_function(ref: str, flag: str) -> Callable[..., Any]:
    """The function `module:function` names, its module imported as `import_env_module` imports an env's (the
    current folder searched too); one sentence naming `flag` when it cannot be found or is not callable."""
    module, _, name = ref.partition(":")
    _search_current_folder()
    try:
        fn = getattr(importlib.import_module(module), name)
    except ImportError as exc:
        why = str(exc).strip().splitlines()[0] if str(exc).strip() else type(exc).__name__
        raise UserError(f"{flag} {ref}: cannot import module {module!r} ({why}); run from the folder that holds it "
                        "or add that folder to PYTHONPATH.") from exc
    except AttributeError:
        raise UserError(f"{flag} {ref}: module {module!r} has no {name!r}; name a function it defines.") from None
    if not callable(fn):
        raise UserError(f"{flag} {ref}: {name!r} in {module!r} is not a function.")
    return fn


def register_recorded_env(spec_json: str | None) -> bool:
    """Register the env a dataset recorded (Gymnasium's `EnvSpec` as JSON) when its id is unknown here and it
    names an importable entry point; returns whether it did. The entry point's module is imported (its import
    usually registers the id itself)."""
    if not spec_json:
        return False
    from gymnasium.envs.registration import EnvSpec

    with contextlib.suppress(Exception):  # a spec this Gymnasium cannot read: the id stays unknown, as before
        spec = EnvSpec.from_json(spec_json)
        if spec.id in gym.registry or not isinstance(spec.entry_point, str) or ":" not in spec.entry_point:
            return False
        _search_current_folder()
        module = spec.entry_point.split(":")[0]
        if module.split(".")[0] in _KNOWN_PACKAGES or importlib.util.find_spec(module.split(".")[0]) is None:
            return False  # the known packages' envs go by their registered ids (an id unknown here stays so)
        importlib.import_module(module)  # most env modules register their ids when imported
        if spec.id not in gym.registry:
            gym.register(spec.id, entry_point=spec.entry_point, max_episode_steps=spec.max_episode_steps,
                         reward_threshold=spec.reward_threshold, nondeterministic=spec.nondeterministic,
                         kwargs=dict(spec.kwargs))
        return True
    return False


def recorded_spec(env_id: str | None) -> str | None:
    """The Gymnasium spec (JSON) of a registered env defined outside digail, Gymnasium and Gymnasium-Robotics:
    what a run folder or an env worker process needs to make it again (None for the others)."""
    with contextlib.suppress(Exception):  # an unknown id or a spec with a callable entry point: nothing to record
        spec = gym.spec(env_id or "")
        entry = spec.entry_point
        if isinstance(entry, str) and ":" in entry and entry.split(".")[0].split(":")[0] not in _KNOWN_PACKAGES:
            return str(spec.to_json())
    return None


_KNOWN_PACKAGES = ("digail", "gymnasium", "gymnasium_robotics")
"""packages whose envs are registered by importing digail (or on demand): no spec to record for them"""


def _search_current_folder() -> None:
    """Let imports find modules in the current folder (the `digail` script, unlike `python -m`, does not)."""
    if os.getcwd() not in sys.path and "" not in sys.path:
        sys.path.append(os.getcwd())
