"""Code of the user's own, named on the command line: envs as `module:EnvId`, D's views as `module:function`.

`--env shuttle_env:Shuttle-v0` imports `shuttle_env` (from the current folder or `PYTHONPATH`), whose import
registers `Shuttle-v0` with Gymnasium, and then stands for `Shuttle-v0` everywhere (run folders, datasets and
checks name the env by its id alone). A dataset or run folder recorded in an env that is not registered here
carries the env's entry point (`shuttle_env:Shuttle`), but a file never decides what code runs: its module is used
only when the user named that module on this command line (`--env shuttle_env:Shuttle-v0`), and otherwise the id
stays unknown and the refusal says which flag allows it.
"""

from __future__ import annotations

import contextlib
import importlib
import importlib.util
import inspect
import os
import sys
from collections.abc import Callable
from typing import Any

import gymnasium as gym

from digail.errors import UserError

_NAMED: set[str] = set()
"""modules the user named on this command line (and that were imported for it): the only ones a name read from a
dataset or a run folder may use"""

_UNNAMED: dict[str, str] = {}
"""env id -> the entry point a dataset or run folder recorded for it, left unimported because no one named its
module: the refusal to make that env says how to allow it"""


def named_by_user(module: str) -> bool:
    """Whether the user named `module` on this command line (an env's or a D view's module)."""
    return module in _NAMED


def unnamed_env_hint(env_id: str) -> str | None:
    """How to allow an env a data file defines in a module no one named (None when no file did)."""
    entry = _UNNAMED.get(env_id)
    if entry is None:
        return None
    module = entry.split(":")[0]
    return (f"a data file defines it in module {module!r}, which digail imports only when you name it: pass "
            f"--env {module}:{env_id} to allow it")


def check_no_module(env_id: str) -> str:
    """`env_id` as Gymnasium may be given it: an id with a `module:` part (which `gym.make` and `gym.spec` would
    import) only when the user named that module on this command line, and then without it; one sentence otherwise
    (such an id came from a dataset or a run folder, which never decide what code runs)."""
    module, sep, name = str(env_id).partition(":")
    if not sep:
        return env_id
    if name and (module in _NAMED or module in sys.modules):  # named, or imported already: no new code runs
        return name
    raise UserError(f"environment id {env_id!r} names module {module!r}, which digail imports only when you name it; "
                    f"pass --env {env_id} to allow it (in Python, import the module first).")


def _check_module_name(module: str, what: str) -> None:
    """Refuse a module name Python cannot import absolutely (relative, empty parts) in one sentence."""
    if not module or any(not part.isidentifier() for part in module.split(".")):
        raise UserError(f"{what}: {module!r} is not an absolute module name (a relative one such as '.views' cannot "
                        "be imported from the command line); name the module as `import` would, e.g. my_views.")


def _import_named(module: str, what: str) -> Any:
    """Import `module`, which the user named for `what`: every failure, a syntax error or an exception of its own
    at import included, is one sentence; the module is then one the data may use (`named_by_user`)."""
    _check_module_name(module, what)
    _search_current_folder()
    try:
        imported = importlib.import_module(module)
    except ImportError as exc:
        why = str(exc).strip().splitlines()[0] if str(exc).strip() else type(exc).__name__
        raise UserError(f"{what}: cannot import module {module!r} ({why}); run from the folder that holds it or add "
                        "that folder to PYTHONPATH.") from exc
    except SyntaxError as exc:
        raise UserError(f"{what}: module {module!r} has a syntax error ({exc.filename}, line {exc.lineno}: "
                        f"{exc.msg}); fix it and run again.") from None
    except (Exception, SystemExit) as exc:  # noqa: BLE001  (the user's module: whatever its import raises, one answer)
        why = " ".join(str(exc).split())[:120]
        raise UserError(f"{what}: importing module {module!r} raised {type(exc).__name__}"
                        f"{': ' + why if why else ''}; fix the module so that it imports cleanly.") from None
    _NAMED.add(module)
    return imported


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
    _import_named(module, f"--env {env_id}")
    return name


def import_function(ref: str, flag: str) -> Callable[..., Any]:
    """The function `module:function` names, its module imported as `import_env_module` imports an env's (the
    current folder searched too); one sentence naming `flag` when it cannot be found or is not a function of one
    argument from the user's own code.

    Python's standard library and builtins are refused before anything is called: a view is the user's function
    of a tensor, and `os:system` or `sys:exit` named by mistake (or by a spec file) must not run."""
    module, _, name = ref.partition(":")
    _check_module_name(module, f"{flag} {ref}")
    if module.split(".")[0] in sys.stdlib_module_names or module.split(".")[0] == "builtins":
        raise UserError(f"{flag} {ref}: {module!r} is part of Python's standard library, not a module of yours; "
                        "name a function (observations -> features) in your own module, e.g. my_views:relative.")
    fn = getattr(_import_named(module, f"{flag} {ref}"), name, None)
    if fn is None:
        raise UserError(f"{flag} {ref}: module {module!r} has no {name!r}; name a function it defines.")
    if not callable(fn) or inspect.isclass(fn) or inspect.isbuiltin(fn):
        raise UserError(f"{flag} {ref}: {name!r} in {module!r} is not a function of yours (observations -> "
                        "features); name one defined with def in that module.")
    try:
        inspect.signature(fn).bind(None)
    except TypeError:
        raise UserError(f"{flag} {ref}: {name!r} in {module!r} does not take one argument (the observations); a "
                        "view is called as f(obs) and returns features.") from None
    except ValueError:
        pass  # no signature to read (some C extensions): the call on the demonstrations checks it
    return fn


def register_recorded_env(spec_json: str | None, *, trusted: bool = False) -> bool:
    """Register the env a dataset or run folder recorded (Gymnasium's `EnvSpec` as JSON) when its id is unknown
    here and its entry point's module is one the user named on this command line; returns whether it did.

    A module no one named is not imported (a file does not decide what code runs): the id stays unknown and
    `unnamed_env_hint` says how to allow it. `trusted` is for the spec this process's parent passes to its env
    workers, which holds only what the user named there."""
    if not spec_json:
        return False
    from gymnasium.envs.registration import EnvSpec

    with contextlib.suppress(Exception):  # a spec this Gymnasium cannot read: the id stays unknown, as before
        spec = EnvSpec.from_json(spec_json)
        if spec.id in gym.registry or not isinstance(spec.entry_point, str) or ":" not in spec.entry_point:
            return False
        module = spec.entry_point.split(":")[0]
        if module.split(".")[0] in _KNOWN_PACKAGES:
            return False  # the known packages' envs go by their registered ids (an id unknown here stays so)
        if not trusted and not named_by_user(module):
            _UNNAMED[spec.id] = spec.entry_point
            return False
        if trusted:
            _search_current_folder()
            if importlib.util.find_spec(module.split(".")[0]) is None:
                return False
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
        if ":" in (env_id or ""):  # an id that would make Gymnasium import a module: never recorded
            return None
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
