"""The command line's table of renamed flags, read before tyro parses.

A renamed flag is refused, not translated: a script that still passes the old name learns the new one in one
sentence (exit status 2) instead of running on with a spelling that may later mean something else.
"""

from __future__ import annotations

from collections.abc import Sequence

from digail.errors import UserError

RENAMED_FLAGS: dict[str, str] = {
    "--bc-weight": "--train.bc-weight",
    "--vae.codes": "--codes",
}
"""old flag -> the flag that replaced it, for every command (no command reuses an old name); a boolean's
`--...no-NAME` form is refused with its new `no-` form too"""


def _spelled(flag: str) -> str:
    """`flag` as the table spells it: tyro reads `--train.bc_weight` as `--train.bc-weight`."""
    return flag.replace("_", "-")


def _negated(flag: str) -> str:
    """The `no-` form of a boolean flag: `--train.shuffle-codes` -> `--train.no-shuffle-codes`."""
    head, _, name = flag[2:].rpartition(".")
    return "--" + (head + "." if head else "") + "no-" + name


def renamed(flag: str) -> str | None:
    """The flag that replaced `flag` (None when `flag` was not renamed)."""
    flag = _spelled(flag)
    if flag in RENAMED_FLAGS:
        return RENAMED_FLAGS[flag]
    for old, new in RENAMED_FLAGS.items():
        if flag == _negated(old):
            return _negated(new)
    return None


def refuse_renamed_flags(argv: Sequence[str]) -> None:
    """Raise a `UserError` naming the new flag when `argv` passes a renamed one (`RENAMED_FLAGS`)."""
    for tok in argv:
        if tok == "--":
            return
        if not tok.startswith("--"):
            continue
        flag = tok.partition("=")[0]
        new = renamed(flag)
        if new is not None:
            raise UserError(f"the flag {flag} is now {new}; pass {new} instead.")
