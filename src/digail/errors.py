"""User-facing errors.

`UserError` marks a problem in what the user gave us (a path, a flag, a dataset). The CLI prints its message as
one sentence and exits with status 2; library callers get an ordinary `ValueError` subclass.
"""

from __future__ import annotations


class UserError(ValueError):
    """Bad input from the user: the message names the problem and the fix."""


class TrainingError(RuntimeError):
    """Training cannot go on (e.g. a NaN loss); the last good checkpoint is kept."""
