"""Composition: run the learned sub-task policies under a code schedule instead of the macro-policy.

The paper's reversed-circles experiment: on Circle-World, schedule "1:60,0:60" asks for code 1's policy first and
code 0's second. Which code learned which circle is arbitrary (`mapping` in the run's segmentation.json); with code
1 the counter-clockwise one, this is the order never demonstrated. `digail run` translates for you.
"""

from __future__ import annotations

import bisect
import itertools
from collections.abc import Sequence
from typing import Any, overload

from digail.errors import UserError
from digail.eval.returns import run_episodes, summarize

MAX_SCHEDULE_STEPS = 1_000_000
"""bound on a schedule's total steps when the environment has no time limit"""


def parse_schedule(text: str, codes: int, max_steps: int | None = None) -> list[tuple[int, int]]:
    """'1:60,0:60' -> [(1, 60), (0, 60)]: (code, steps) pairs, never expanded step by step.

    Every code must be below `codes`, every step count at least 1, and the total at most `max_steps` (an
    episode's time limit: steps past it could never run; the last code holds once the schedule is over, so a
    shorter schedule is always fine), or `MAX_SCHEDULE_STEPS` when the env has no limit.

    Raises:
        UserError: one sentence naming what is wrong with the schedule.
    """
    limit = MAX_SCHEDULE_STEPS if max_steps is None else int(max_steps)
    pairs: list[tuple[int, int]] = []
    total = 0
    for part in str(text).split(","):
        fields = part.strip().split(":")
        if len(fields) != 2 or not all(f.strip().isdigit() and f.strip().isascii() for f in fields):
            raise UserError(f"cannot read the schedule {text[:60]!r}{'...' if len(text) > 60 else ''}; write "
                            "code:steps pairs such as '1:60,0:60'.")
        code_s, steps_s = (f.strip() for f in fields)
        if len(code_s) > 12 or not 0 <= int(code_s) < codes:
            raise UserError(f"the schedule uses code {code_s[:12]}{'...' if len(code_s) > 12 else ''} but the "
                            f"policy has {codes} codes (0 to {codes - 1}).")
        # compare digit counts before converting, so a 10**6-digit number costs nothing
        exact = len(steps_s) <= len(str(limit)) + 1
        steps = int(steps_s) if exact else limit + 1
        if steps < 1:
            raise UserError(f"every step count of the schedule must be at least 1, got {code_s}:{steps_s}.")
        total += steps
        if total > limit:
            span = f"{total:,} steps" if exact else "over a million steps" if limit >= 10**6 else \
                f"more than {limit:,} steps"
            what = f"an episode ({limit:,} steps at most)" if max_steps is not None else f"{limit:,} steps"
            raise UserError(f"the schedule lasts {span}, longer than {what}; shorten it (the last code holds "
                            "until the episode ends).")
        pairs.append((int(code_s), steps))
    return pairs


class CodeSchedule(Sequence[int]):
    """The code at each step of (code, steps) pairs, looked up by bisection instead of a list of every step."""

    def __init__(self, pairs: Sequence[tuple[int, int]]) -> None:
        self.pairs = [(int(c), int(n)) for c, n in pairs]
        self._ends = list(itertools.accumulate(n for _, n in self.pairs))

    def __len__(self) -> int:
        return self._ends[-1] if self._ends else 0

    @overload
    def __getitem__(self, t: int) -> int: ...

    @overload
    def __getitem__(self, t: slice) -> list[int]: ...

    def __getitem__(self, t: int | slice) -> int | list[int]:
        if isinstance(t, slice):
            return [self[i] for i in range(*t.indices(len(self)))]
        if t < 0:
            t += len(self)
        if not 0 <= t < len(self):
            raise IndexError(t)
        return self.pairs[bisect.bisect_right(self._ends, t)][0]


def episode_limit(env_id: str) -> int | None:
    """The env's time limit in steps (None when it has none)."""
    from digail.envs import make_env

    env = make_env(env_id)
    try:
        limit = env.spec.max_episode_steps if env.spec is not None else None
    finally:
        env.close()
    return int(limit) if limit else None


def compose(model: Any, env_id: str, schedule: Sequence[tuple[int, int]], episodes: int, seed: int,
            keep_obs: int = 8) -> tuple[dict[str, Any], list[Any]]:
    """Roll out under the (code, steps) pairs of `schedule`; returns the summary and the episodes (the first
    `keep_obs` keep observations)."""
    codes = CodeSchedule(schedule)
    eps = run_episodes(model, env_id, episodes, seed, deterministic=True, schedule=codes, keep_obs=keep_obs)
    out = summarize(eps, env_id)
    out.update(env_id=env_id, seed=seed, schedule_length=len(codes))
    return out, eps


def schedule_in_codes(pairs: tuple[tuple[int, int], ...], mapping: dict[str, int]) -> str | None:
    """'code:steps,...' for label-level `pairs`, using a segmentation's code -> label `mapping`; None when some
    label has no code of its own (a collapsed segmentation cannot be composed)."""
    by_label: dict[int, int] = {}
    for code, label in mapping.items():
        by_label.setdefault(int(label), int(code))
    if any(label not in by_label for label, _ in pairs) or len({by_label[lb] for lb, _ in pairs}) < len(
            {lb for lb, _ in pairs}):
        return None
    return ",".join(f"{by_label[label]}:{steps}" for label, steps in pairs)
