"""User-facing errors.

`UserError` marks a problem in what the user gave us (a path, a flag, a dataset). The CLI prints its message as
one sentence and exits with status 2; library callers get an ordinary `ValueError` subclass.
"""

from __future__ import annotations

from pathlib import Path


class UserError(ValueError):
    """Bad input from the user: the message names the problem and the fix."""


class TrainingError(RuntimeError):
    """Training cannot go on (e.g. a NaN loss); the last good checkpoint is kept."""


class OldOutputLeft(UserError):
    """`--force` replaced an output, but what is left of the old one could not be removed: the new output is in
    place (the command's work is done) and the sentence names the leftover folder to remove by hand."""

    def __init__(self, final: Path, old: Path, reason: str) -> None:
        self.final, self.old, self.reason = Path(final), Path(old), reason
        super().__init__(self.sentence(f"the new {final} is in place"))

    def sentence(self, done: str) -> str:
        """The refusal after `done` (what is in place), e.g. "the new OUT is in place"."""
        return (f"{done}, but the old {self.final} could not be removed ({self.reason}); what is left of it is in "
                f"{self.old}, remove it by hand.")
