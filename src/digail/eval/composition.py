"""Composition: run the learned sub-task policies under a code schedule instead of the macro-policy.

The paper's reversed-circles experiment: on Circle-World, schedule "1:60,0:60" asks for code 1's policy first and
code 0's second. Which code learned which circle is arbitrary (`mapping` in the run's segmentation.json); with code
1 the counter-clockwise one, this is the order never demonstrated. `digail run` translates for you.
"""

from __future__ import annotations

from typing import Any

from digail.errors import UserError
from digail.eval.returns import run_episodes, summarize


def parse_schedule(text: str, codes: int) -> list[int]:
    """'1:60,0:60' -> sixty 1s then sixty 0s; every code must be below `codes`."""
    out: list[int] = []
    try:
        for part in text.split(","):
            code_s, steps_s = part.strip().split(":")
            code, steps = int(code_s), int(steps_s)
            if steps <= 0:
                raise ValueError
            out += [code] * steps
    except ValueError:
        raise UserError(f"cannot read the schedule {text!r}; write code:steps pairs such as '1:60,0:60'.") from None
    bad = sorted({c for c in out if not 0 <= c < codes})
    if bad:
        raise UserError(f"the schedule uses code(s) {bad} but the policy has {codes} codes (0 to {codes - 1}).")
    return out


def compose(model: Any, env_id: str, schedule: list[int], episodes: int, seed: int,
            keep_obs: int = 8) -> tuple[dict[str, Any], list[Any]]:
    """Roll out under `schedule`; returns the summary and the episodes (first `keep_obs` keep observations)."""
    eps = run_episodes(model, env_id, episodes, seed, deterministic=True, schedule=schedule, keep_obs=keep_obs)
    out = summarize(eps)
    out.update(env_id=env_id, seed=seed, schedule_length=len(schedule))
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
