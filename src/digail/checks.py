"""The value checks every command shares: seeds, counts, the number of codes, and the numbers of a config.

Each raises the one-sentence `UserError` naming the flag, so a bad value stops a command before any work.
"""

from __future__ import annotations

from typing import Any

from digail.errors import UserError


def _require(ok: bool, flag: str, rule: str, value: Any) -> None:
    """Raise the one-sentence `UserError` naming `flag` unless `ok` (configs check their numbers on creation, so a
    bad override stops the command before any work, whichever way the config was made)."""
    if not ok:
        raise UserError(f"{flag} must be {rule}, got {value!r}.")


SEED_MAX = 2**32 - 1
"""largest seed: NumPy's legacy seeding and many environments take 32-bit seeds"""


def check_seed(seed: int, flag: str = "--seed", count: int = 1, count_flag: str = "--episodes") -> None:
    """A seed in 0..2**32-1; with `count` consecutive per-episode seeds (`count_flag`), the last one too."""
    if isinstance(count, int) and count > SEED_MAX + 1:  # no seed could start them: say what is too many
        raise UserError(f"{count_flag} must be at most {SEED_MAX + 1} (each episode has a seed of its own, and there "
                        f"are no more), got {count}.")
    _require(isinstance(seed, int) and 0 <= seed <= SEED_MAX - max(count - 1, 0), flag,
             f"between 0 and {SEED_MAX - max(count - 1, 0)}" + (f" (episode i uses {flag.lstrip('-')} + i)"
                                                                  if count > 1 else ""), seed)


def check_at_least(value: int | None, flag: str, low: int = 1) -> None:
    """A count such as --episodes: at least `low` (None: the default applies)."""
    if value is not None:
        _require(isinstance(value, int) and value >= low, flag, f"at least {low}", value)


def check_codes(codes: int) -> None:
    """The number of sub-task codes K: at least 1 (`--codes`)."""
    _require(isinstance(codes, int) and not isinstance(codes, bool) and codes >= 1, "--codes", "at least 1", codes)


FINAL_EVAL_SEED = 10_000
"""seed of the first episode of every final evaluation (episode i uses seed + i); training never uses it"""


def _finite(x: float) -> bool:
    return x == x and x not in (float("inf"), float("-inf"))


def _check_numbers(cfg: Any, prefix: str, at_least: dict[str, int], non_negative: tuple[str, ...] = (),
                   unit: tuple[str, ...] = ()) -> None:
    """Integers with a minimum, non-negative finite floats and [0, 1] fractions of config `cfg`; flags are named
    `prefix` + the field with dashes (how tyro spells them)."""
    def flag(name: str) -> str:
        return prefix + name.replace("_", "-")

    for name, low in at_least.items():
        v = getattr(cfg, name)
        _require(isinstance(v, int) and v >= low, flag(name), f"at least {low}", v)
    for name in non_negative:
        v = getattr(cfg, name)
        if v is not None:
            _require(_finite(float(v)) and v >= 0, flag(name), "a finite number, not negative", v)
    for name in unit:
        v = getattr(cfg, name)
        _require(_finite(float(v)) and 0 <= v <= 1, flag(name), "between 0 and 1", v)
