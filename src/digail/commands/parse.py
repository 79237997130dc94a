"""A subcommand's command line parsed into its argument dataclass (tyro), and the command run on it.

Here, below `digail.cli`, so that a preset's values (`defaults(argv)`) and the flags parsed over them go from the
command's module straight on to its function: the arguments never travel back up to the dispatcher.
"""

from __future__ import annotations

import contextlib
import re
from collections.abc import Callable, Iterator, Sequence
from typing import Any

import tyro

from digail.commands.flags import HELP_ALL, STUDY_SETTINGS, help_text, help_view, without_flags
from digail.errors import UserError


def parse_and_run(cls: type, handler: Callable[[Any], Any], defaults: Callable[[Sequence[str]], Any] | None,
                  argv: Sequence[str], prog: str) -> None:
    """Parse `argv` into `cls` (defaults from `defaults(argv)` where the command has them: the preset the command
    line asks for) and run `handler` on the result; a parse error is one `UserError` sentence."""
    default = defaults(argv) if defaults is not None else None
    hidden = STUDY_SETTINGS.get(prog.split()[-1], ())  # prog is "digail COMMAND"
    if HELP_ALL in argv:
        show_help(cls, default, ["--help" if tok == HELP_ALL else tok for tok in argv], prog, ())
    elif any(tok in ("-h", "--help") for tok in argv):
        show_help(cls, default, argv, prog, hidden)
    with parse_errors_as_user_errors(argv):
        args = tyro.cli(cls, args=list(argv), prog=prog, default=default, description=cls.__doc__)
    handler(args)


def show_help(cls: type, default: Any, argv: Sequence[str], prog: str, hidden: Sequence[str]) -> None:
    """Print `prog --help` (`flags.help_view`: without the settings at `hidden`, study switches and optimiser
    internals) and exit; where some are left out, the description ends by saying how many and how to see them."""
    view, view_default = help_view(cls, default, hidden)
    kept = without_flags(argv, hidden)  # the view has no such flags; with --help their values change nothing
    note = (f"\n{len(hidden)} study and ablation switches and optimiser internals are left out here; "
            f"`{prog} {HELP_ALL}` lists every flag, and the configuration reference says what each is for."
            if hidden else "")
    with parse_errors_as_user_errors(kept):
        tyro.cli(view, args=list(kept), prog=prog, default=view_default,
                 description=help_text(cls.__doc__ or "") + note)


_TYPE_WORDS = {"INT": "an integer", "FLOAT": "a number", "PATH": "a path", "STR": "a string",
               "{True,False}": "True or False", "{None}": "None"}


def _expected(metavar: Any) -> str:
    """tyro's metavar in words: 'INT' -> 'an integer', '{a,b}' -> 'one of a, b', '[INT [INT ...]]' -> integers."""
    text = str(metavar or "a value")
    if text in _TYPE_WORDS:
        return _TYPE_WORDS[text]
    if "|" in text:
        return " or ".join(_expected(part) for part in text.split("|"))
    if text.startswith("{") and text.endswith("}"):
        return "one of " + ", ".join(text[1:-1].split(","))
    words = re.findall(r"[A-Z]+", text)
    if "..." in text and words and words[0] in _TYPE_WORDS:
        return f"one or more {_TYPE_WORDS[words[0]].split(' ', 1)[1]}s ({text})"
    return text


def _given(flag: str, argv: Sequence[str]) -> str | None:
    """The value `flag` was given on the command line, for the message."""
    for i, tok in enumerate(argv):
        if tok == flag and i + 1 < len(argv):
            return argv[i + 1]
        if tok.startswith(flag + "="):
            return tok[len(flag) + 1:]
    return None


@contextlib.contextmanager
def parse_errors_as_user_errors(argv: Sequence[str]) -> Iterator[None]:
    """Turn tyro's boxed parse errors into one `UserError` sentence naming the flag and what it expects."""
    try:
        from tyro import _errors as tyro_errors
    except ImportError:  # an older tyro: its own (multi-line) message, still exit status 2
        yield
        return

    def flag_of(arg: Any) -> str:
        names = [str(n) for n in getattr(arg.lowered, "name_or_flags", ()) or ()]
        return names[-1] if names and names[-1].startswith("-") else arg.field.intern_name.upper()

    def hook(event: Any) -> None:
        if isinstance(event, tyro_errors.InstantiationFailure):
            if event.argument is None:  # a config's __post_init__ refused the values: its sentence as it is
                raise UserError(event.message)
            flag = flag_of(event.argument)
            value = _given(flag, argv)
            got = f", got {value!r}" if value is not None else f" ({event.message})"
            raise UserError(f"{flag} expects {_expected(event.argument.lowered.metavar)}{got}.")
        if isinstance(event, tyro_errors.MissingArgs):
            flags = [flag_of(a.arg) for a in event.missing_arguments]
            kind = "flag" if flags[0].startswith("-") else "argument"
            plural = "s" if len(flags) > 1 else ""
            raise UserError(f"the {kind}{plural} {', '.join(flags)} {'are' if plural else 'is'} missing; see "
                            f"`{event.prog} --help`.")
        if isinstance(event, tyro_errors.InvalidChoice):
            raise UserError(f"{flag_of(event.argument)} must be one of {', '.join(event.choices)}, got "
                            f"{event.value!r}.")
        if isinstance(event, tyro_errors.BadValue):
            arg = event.argument
            if event.offending_value is not None:
                raise UserError(f"{flag_of(arg)} takes no value, got {event.offending_value!r}.")
            raise UserError(f"{flag_of(arg)} expects {_expected(arg.lowered.metavar)} and was given none.")
        if isinstance(event, tyro_errors.UnrecognizedArgs):
            raise UserError(f"unknown option{'s' if len(event.tokens) > 1 else ''} {' '.join(event.tokens)}; see "
                            f"`{event.prog} --help`.")
        raise UserError(f"cannot read the command line ({type(event).__name__}); see `{event.prog} --help`.")

    with tyro_errors.on_parse_error(hook):
        yield
