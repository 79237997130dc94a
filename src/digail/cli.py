"""The `digail` command line: the table of subcommands and `main`.

Each subcommand lives in `digail.commands.<name>` with its argument dataclass (parsed by tyro), the function that
runs it and, where nested configs start from a preset, a `defaults(argv)` function. Bad input raises `UserError`,
printed as one sentence with exit status 2.
"""

from __future__ import annotations

import contextlib
import dataclasses
import errno
import os
import signal
import sys
from collections.abc import Iterator, Sequence
from types import ModuleType
from typing import Any

from digail.commands.flags import refuse_renamed_flags
from digail.commands.parse import parse_and_run
from digail.errors import TrainingError, UserError

COMMANDS: dict[str, tuple[str, str]] = {
    "demos": ("DemosArgs", "demos_command"),
    "import": ("ImportArgs", "import_command"),
    "pretrain": ("PretrainArgs", "pretrain_command"),
    "segment": ("SegmentArgs", "segment_command"),
    "train": ("TrainArgs", "train_command"),
    "evaluate": ("EvaluateArgs", "evaluate_command"),
    "compose": ("ComposeArgs", "compose_command"),
    "generate": ("GenerateArgs", "generate_command"),
    "run": ("RunArgs", "run_command"),
    "expert": ("ExpertArgs", "expert_command"),
    "video": ("VideoArgs", "video_command"),
    "report": ("ReportArgs", "report_command"),
    "sweep": ("SweepArgs", "sweep_command"),
}
"""subcommand -> (argument dataclass, function) in the module `digail.commands.<subcommand>` (`<subcommand>_` for a
Python keyword: `import_`)"""


def _module(name: str) -> ModuleType:
    """The module of subcommand `name`, imported only now (a command's heavy imports wait until it runs). Each
    import is written out, not built from a string, so that the layer contract sees `cli` above `commands`."""
    match name:
        case "demos":
            from digail.commands import demos

            return demos
        case "pretrain":
            from digail.commands import pretrain

            return pretrain
        case "segment":
            from digail.commands import segment

            return segment
        case "train":
            from digail.commands import train

            return train
        case "evaluate":
            from digail.commands import evaluate

            return evaluate
        case "compose":
            from digail.commands import compose

            return compose
        case "generate":
            from digail.commands import generate

            return generate
        case "run":
            from digail.commands import run

            return run
        case "expert":
            from digail.commands import expert

            return expert
        case "video":
            from digail.commands import video

            return video
        case "report":
            from digail.commands import report

            return report
        case "sweep":
            from digail.commands import sweep

            return sweep
        case "import":
            from digail.commands import import_

            return import_
    raise KeyError(name)


def _command(name: str) -> tuple[Any, Any, Any]:
    """The argument class, the function and the optional `defaults(argv)` of subcommand `name`."""
    module = _module(name)
    args_cls, fn = COMMANDS[name]
    return getattr(module, args_cls), getattr(module, fn), getattr(module, "defaults", None)


def _usage() -> str:
    lines = ["usage: digail COMMAND [ARGS] ...", "",
             "Directed-Info GAIL: sub-task discovery and hierarchical imitation.",
             "", "commands:"]
    width = max(map(len, COMMANDS))
    for name in COMMANDS:
        first = (_command(name)[0].__doc__ or "").strip().splitlines()[0]
        lines.append(f"  {name:<{width}}  {first}")
    lines += ["", "`digail COMMAND --help` shows a command's options (`--help-all`: its study switches as well)."]
    return "\n".join(lines)


def main(argv: Sequence[str] | None = None) -> int:
    """Entry point of the `digail` console script; returns the exit status."""
    try:
        return _main(argv)
    except KeyboardInterrupt:
        # Ctrl-C while the command was still importing its libraries, before its own handler (`Interrupted`) was
        # set: nothing has been read or written yet
        args = list(sys.argv[1:] if argv is None else argv)
        name = f" {args[0]}" if args and args[0] in COMMANDS else ""
        print(f"digail{name}: stopped by SIGINT before it began; nothing was written.", file=sys.stderr)
        return 128 + signal.SIGINT
    except BrokenPipeError:
        # the reader went away (`digail ... | head`): stop quietly, as a Unix tool killed by SIGPIPE does, and
        # point the standard streams at /dev/null so that the interpreter's final flush does not complain
        with contextlib.suppress(OSError, ValueError):
            devnull = os.open(os.devnull, os.O_WRONLY)
            for stream in (sys.stdout, sys.stderr):
                os.dup2(devnull, stream.fileno())
        return 128 + signal.SIGPIPE


def _main(argv: Sequence[str] | None) -> int:
    argv = list(sys.argv[1:] if argv is None else argv)
    if not argv or argv[0] in ("-h", "--help"):
        print(_usage())
        return 0 if argv else 2
    name, rest = argv[0], argv[1:]
    if name not in COMMANDS:
        print(f"digail: unknown command {name!r}; run `digail --help` for the list.", file=sys.stderr)
        return 2
    from digail.utils import ensure_offscreen_gl, set_torch_threads

    ensure_offscreen_gl()  # before anything imports MuJoCo: egl, or osmesa where there is no EGL

    set_torch_threads(1)  # small nets: a second thread buys nothing and costs much under load
    cls, handler, defaults = _command(name)
    try:
        refuse_renamed_flags(rest)
        _check_utf8(rest)
        with _terminate_as_interrupt():
            takes_env = any(f.name == "env" for f in dataclasses.fields(cls))
            rest = _env_modules_imported(name, rest, takes_env)
            parse_and_run(cls, handler, defaults, rest, prog=f"digail {name}")
    except UserError as exc:
        print(f"digail {name}: error: {_one_sentence(exc)}", file=sys.stderr)
        return 2
    except TrainingError as exc:  # training cannot go on (a NaN loss): one sentence, exit 1, the checkpoint kept
        print(f"digail {name}: error: {_one_sentence(exc)}", file=sys.stderr)
        return 1
    except SystemExit as exc:  # tyro / argparse: --help exits 0 (parse errors arrive as UserError above)
        return int(exc.code or 0) if isinstance(exc.code, int | None) else 2
    except Interrupted as exc:
        hint = f"; continue it with `digail {name} --resume RUN`" if name in ("train", "run") else ""
        print(f"digail {name}: stopped by {exc.signame}, no temporary files left{hint}.", file=sys.stderr)
        return 128 + exc.signum
    except OSError as exc:
        if exc.errno not in _DISK_ERRORS:
            raise
        where = f" at {exc.filename}" if exc.filename else ""
        fix = ("raise the file-size limit (`ulimit -f`) or choose another --out" if exc.errno == errno.EFBIG
               else "free some space, fix the permissions or choose another --out")
        print(f"digail {name}: error: {os.strerror(exc.errno or 0).lower()}{where}; {fix}.", file=sys.stderr)
        return 2
    return 0


def _check_utf8(argv: list[str]) -> None:
    """Refuse an argument that is not valid UTF-8 (a path with bytes from another encoding): digail writes paths
    into config.json, reports and messages as text, which it could not do after the work is done."""
    for tok in argv:
        try:
            tok.encode("utf-8")
        except UnicodeEncodeError:
            shown = os.fsencode(tok).decode("utf-8", "backslashreplace")
            raise UserError(f"the argument '{shown}' is not valid UTF-8; rename the file or folder (or choose "
                            "another path) so that its name is UTF-8 text.") from None


POSITIONAL_ENV = ("run", "demos", "expert")
"""commands whose first argument is the env id (`module:EnvId` imports its module, as `--env` does)"""


def _env_modules_imported(name: str, argv: list[str], takes_env: bool = True) -> list[str]:
    """`argv` with each `module:EnvId` (the value of `--env`, or the first argument of `run`, `demos` and
    `expert`) replaced by `EnvId` once its module is imported: the env is then known under its id alone, as
    datasets record it.

    A command on a run folder (`evaluate`, `report`, ...) has no `--env` of its own (`takes_env` False): there
    `--env module:EnvId` only names the module that the run folder's env comes from, the one way a module the
    folder records is ever imported, and leaves the command line."""
    from digail.user_envs import import_env_module

    out: list[str] = []
    skip = False
    for i, tok in enumerate(argv):
        if skip:
            skip = False
            continue
        value = tok.split("=", 1)[1] if tok.startswith("--env=") else argv[i + 1] if (
            tok == "--env" and i + 1 < len(argv)) else None
        if value is not None and not takes_env and ":" in value:
            import_env_module(value)
            skip = tok == "--env"
        elif tok.startswith("--env="):
            out.append("--env=" + import_env_module(value or ""))
        elif i > 0 and argv[i - 1] == "--env" or name in POSITIONAL_ENV and i == 0 and not tok.startswith("-"):
            out.append(import_env_module(tok))
        else:
            out.append(tok)
    return out


_DISK_ERRORS = {errno.ENOSPC, errno.EDQUOT, errno.EROFS, errno.EACCES, errno.EPERM, errno.EFBIG}
"""OSErrors of the disk rather than of the program: reported as one sentence, exit 2"""


class Interrupted(KeyboardInterrupt):
    """SIGINT or SIGTERM arrived: unwinds like Ctrl-C, so every `atomic_dir` removes its temporary folder."""

    def __init__(self, signum: int) -> None:
        super().__init__(signum)
        self.signum = signum
        self.signame = signal.Signals(signum).name


def _raise_interrupted(signum: int, frame: Any) -> None:
    raise Interrupted(signum)


@contextlib.contextmanager
def _terminate_as_interrupt() -> Iterator[None]:
    """SIGTERM (what `timeout` and job schedulers send) and SIGINT raise `Interrupted` for the block's duration
    (main thread only: elsewhere signals cannot be caught and the default handlers stay)."""
    import threading

    if threading.current_thread() is not threading.main_thread():
        yield
        return
    old = {s: signal.signal(s, _raise_interrupted) for s in (signal.SIGTERM, signal.SIGINT)}
    try:
        yield
    finally:
        for s, handler in old.items():
            signal.signal(s, handler)


def _one_sentence(exc: BaseException) -> str:
    """A UserError's message on one line (tracebacks and torch's advice never reach the user)."""
    return " ".join(str(exc).split())


if __name__ == "__main__":
    sys.exit(main())
