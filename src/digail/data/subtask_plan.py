"""The sub-tasks a robomimic export names for MimicGen, and one boundary per sub-task in every demonstration.

MimicGen's parser (`parse_source_dataset`) takes the signals of a task spec in order and ends sub-task i at the
first 0 -> 1 step of its signal after sub-task i - 1 ended, so every demonstration needs one such step per named
sub-task, in one order. `plan_subtasks` decides that order once for a file and fits each demonstration's
boundaries; `settle_grasps` moves a boundary that follows a finger motion in its sub-task to where the fingers
stopped, since MimicGen's signals mark the grasp made, the codes the command to make it or the arm's next move.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, replace

import numpy as np

from digail.errors import UserError


def demonstrated_order(codes: Sequence[np.ndarray], n_codes: int) -> list[int]:
    """Every code, in the order the demonstrations take them: first the codes that occur in at least half of the
    demonstrations (at least the most common one), by the median over demonstrations of where each first occurs
    (as a fraction of the demonstration; ties by code number), then the rarer codes the same way, then the codes
    that never occur, by number. MimicGen's export takes its sub-tasks in this order (`plan_subtasks`)."""
    codes = [np.asarray(c).reshape(-1) for c in codes]
    present = np.array([sum(bool((c == k).any()) for c in codes) for k in range(n_codes)])
    common = _common_codes(present, len(codes))
    where = {k: float(np.median([np.flatnonzero(c == k)[0] / len(c) for c in codes if (c == k).any()]))
             for k in range(n_codes) if present[k]}
    rare = [k for k in where if k not in common]
    return [*sorted(common, key=lambda k: (where[k], k)), *sorted(rare, key=lambda k: (where[k], k)),
            *[k for k in range(n_codes) if not present[k]]]


def _common_codes(present: np.ndarray, n_demos: int) -> list[int]:
    """The codes found in at least half of `n_demos` demonstrations (`present[k]`: how many hold code k), or the
    most common one when none is."""
    common = [k for k in range(len(present)) if 2 * present[k] >= n_demos and present[k] > 0]
    return common or [int(np.argmax(present))]


def names_by_code(names: Sequence[str], codes: Sequence[np.ndarray]) -> list[str]:
    """The user's `--names`, given in the demonstrated order, as one name per code number: the first name goes to
    the code the demonstrations take first (`demonstrated_order`), whatever its number, so the names never depend
    on which code a training happened to give which sub-task."""
    out = [""] * len(names)
    for name, code in zip(names, demonstrated_order(codes, len(names)), strict=True):
        out[code] = name
    return out


@dataclass(frozen=True)
class SubtaskPlan:
    """The sub-tasks an export names for MimicGen and each demonstration's boundaries between them.

    MimicGen's parser takes the signals of a task spec in order and ends sub-task i at the first 0 -> 1 step of
    its signal after sub-task i - 1 ended; every demonstration needs one such step per named sub-task, in the same
    order. Codes that recur, or segments that differ in number between demonstrations, do not give that by
    themselves, so the export decides the order once for the dataset and one boundary per sub-task per
    demonstration (`plan_subtasks`).
    """

    order: tuple[int, ...]
    """the codes taken as sub-tasks, in the demonstrated order (the last one ends with the demonstration)"""
    boundaries: tuple[tuple[int, ...], ...]
    """per demonstration, the first step of each sub-task after the first (len(order) - 1 strictly increasing
    steps): the step where the signal of the sub-task before it turns 1"""
    unused: tuple[int, ...]
    """codes occurring in fewer than half of the demonstrations, written as all-zero signals"""
    refitted: int
    """demonstrations whose codes are not one run of each sub-task in `order` (a code recurs, is missing, comes
    out of order or is an unused one), whose boundaries were fitted"""
    settled: int = 0
    """boundaries moved to where a nearby finger motion ended (`settle_grasps`)"""
    merged: tuple[int, ...] = ()
    """codes whose sub-task was too short and went into its neighbour (`merge_short`), written as all-zero"""
    short: tuple[tuple[int, int, int], ...] = ()
    """(demonstration, sub-task position, steps) of the sub-tasks still shorter than `merge_short`'s minimum"""
    min_steps: int = 0
    """`merge_short`'s minimum"""


def plan_subtasks(codes: Sequence[np.ndarray], n_codes: int, keys: Sequence[str] | None = None) -> SubtaskPlan:
    """MimicGen sub-tasks and one boundary per sub-task for every demonstration, whatever the segmentation.

    The sub-tasks are the codes that occur in at least half of the demonstrations (at least the most common code),
    ordered by the median over demonstrations of where each first occurs (as a fraction of the demonstration; ties
    by code number). Each demonstration's boundaries are the labelling into those sub-tasks, in that order, each
    sub-task one contiguous run, that agrees with the most of its steps' codes (exact, by dynamic programming; ties
    go to the earlier boundary). Every sub-task gets at least one step and the last at least two, since MimicGen's
    parser puts the first step a signal is 1 into the sub-task that ended. A demonstration coded as one run of
    each sub-task in order (the last run at least two steps) keeps its runs' ends, as `term_signals` gives them.

    Args:
        codes: one (T,) array of codes per demonstration.
        n_codes: K, the number of codes (and of signals written).
        keys: each demonstration's name, for the error (default: its position).

    Raises:
        UserError: a demonstration too short to hold every sub-task.
    """
    codes = [np.asarray(c).reshape(-1) for c in codes]
    n = len(codes)
    used = _common_codes(np.array([sum(bool((c == k).any()) for c in codes) for k in range(n_codes)]), n)
    order = tuple(demonstrated_order(codes, n_codes)[:len(used)])
    need = len(order) + 1 if len(order) > 1 else 1  # one sub-task: nothing to cut
    boundaries, refitted = [], 0
    for i, c in enumerate(codes):
        if len(c) < need:
            name = keys[i] if keys is not None else f"demonstration {i}"
            raise UserError(f"{name} has {len(c)} steps, too few for the {len(order)} sub-tasks the "
                            f"segmentation names (MimicGen needs at least {need}); drop it or segment with fewer "
                            "codes.")
        cuts = _best_monotone_cuts(c, order)
        runs = [int(c[0]), *[int(c[j]) for j in np.flatnonzero(np.diff(c)) + 1]]
        refitted += runs != list(order)
        boundaries.append(cuts)
    unused = tuple(k for k in range(n_codes) if k not in order)
    return SubtaskPlan(order=order, boundaries=tuple(boundaries), unused=unused, refitted=refitted)


def _best_monotone_cuts(codes: np.ndarray, order: Sequence[int]) -> tuple[int, ...]:
    """The start steps of sub-tasks 1 .. S-1 maximising the steps whose code is their sub-task's (see
    `plan_subtasks`): f[i][b] is the best agreement of steps before b with sub-task i starting at b."""
    t_len, s = len(codes), len(order)
    agree = np.stack([np.concatenate([[0], np.cumsum(codes == k)]) for k in order])  # agree[i][t]: steps < t
    minimum = [1] * (s - 1) + [2]
    best = np.full((s, t_len + 1), -np.inf)
    back = np.zeros((s, t_len + 1), dtype=np.int64)
    best[0, 0] = 0.0
    steps = np.arange(t_len + 1)
    for i in range(1, s):  # sub-task i starts at b, sub-task i - 1 started at the best a <= b - minimum[i - 1]
        vals = best[i - 1] - agree[i - 1]
        run_max = np.maximum.accumulate(vals)
        new_max = vals > np.concatenate([[-np.inf], run_max[:-1]])  # strict: ties keep the earlier start
        run_arg = np.maximum.accumulate(np.where(new_max, steps, 0))
        a = steps[minimum[i - 1]:] - minimum[i - 1]
        best[i, minimum[i - 1]:] = agree[i - 1, minimum[i - 1]:] + run_max[a]
        back[i, minimum[i - 1]:] = run_arg[a]
    total = np.where(steps <= t_len - minimum[-1], best[s - 1] + agree[s - 1, t_len] - agree[s - 1], -np.inf)
    b = int(np.argmax(total))  # argmax: the first of equal totals
    cuts = []
    for i in range(s - 1, 0, -1):
        cuts.append(b)
        b = int(back[i, b])
    return tuple(reversed(cuts))


def plan_signals(plan: SubtaskPlan, demo: int, n_steps: int, n_codes: int) -> np.ndarray:
    """(n_codes, n_steps) int64 termination signals of one demonstration under `plan`, MimicGen's convention:
    sub-task i's signal is 0 before the boundary that ends it and 1 from there on; the last sub-task's and the
    unused codes' stay 0."""
    out = np.zeros((n_codes, n_steps), dtype=np.int64)
    for code, start in zip(plan.order[:-1], plan.boundaries[demo], strict=True):
        out[code, start:] = 1
    return out


def term_signals(codes: np.ndarray, n_steps: int, n_codes: int) -> np.ndarray:
    """(n_codes, n_steps) int64 termination signals of one demonstration's codes on its own (`plan_subtasks` of
    that one demonstration): for codes that run once each, code k's signal is 0 until its segment ends and 1 from
    the next step on; a code that never occurs, or the last sub-task, stays 0."""
    codes = np.asarray(codes).reshape(-1)
    return plan_signals(plan_subtasks([codes[:n_steps]], n_codes), 0, n_steps, n_codes)


def plan_line(plan: SubtaskPlan, names: Sequence[str]) -> str:
    """The one line an export prints about `plan`: the order to give MimicGen's task spec and what was fitted."""
    ordered = [names[k] for k in plan.order]
    line = (f"MimicGen sub-tasks in the demonstrated order: {', '.join(ordered)} (task spec signals: "
            f"{', '.join([*ordered[:-1], 'None'])})")
    if plan.refitted:
        line += (f"; {plan.refitted} of {len(plan.boundaries)} demonstrations have codes that recur, are missing or "
                 "come out of that order, and got the one boundary per sub-task that agrees with most of their steps")
    if plan.settled:
        line += f"; {plan.settled} boundaries moved to where the gripper's fingers stopped (the grasp or release)"
    if plan.merged:
        line += (f"; {', '.join(names[k] for k in plan.merged)} (sub-tasks of a median under {plan.min_steps} "
                 "steps) merged into the next and written as all-zero")
    rare = [k for k in plan.unused if k not in plan.merged]
    if rare:
        line += (f"; {', '.join(names[k] for k in rare)} (in fewer than half of the demonstrations) "
                 "written as all-zero")
    return line


MIN_SUBTASK_STEPS = 20
"""the fewest steps a MimicGen sub-task should have (by its median over the demonstrations): MimicGen's task
configs move each sub-task's end by up to 20 steps (`subtask_term_offset_range`, (10, 20) for Stack), and its
parser refuses a demonstration where that moves an end past the next one"""


MIN_SUBTASK_SHARE = 0.1
"""a sub-task is merged only if it is also under this share of the median demonstration, so short demonstrations
keep their sub-tasks"""


def merge_short(plan: SubtaskPlan, lengths: Sequence[int], min_steps: int | None = None) -> SubtaskPlan:
    """`plan` with the shortest sub-task (by its median length over the demonstrations) merged into the next one
    (the last into the one before) while it is under `min_steps` and more than one is left: its boundary goes, and
    its code's signal is written all-zero. `min_steps` defaults to `MIN_SUBTASK_STEPS` or `MIN_SUBTASK_SHARE` of
    the median demonstration, whichever is fewer. Demonstrations whose sub-tasks are still shorter are listed in `short`
    for the export to name. On robosuite's Stack the default K = 4 cut the reach into two short pieces before the
    grasp (about 9 and 10 steps), which MimicGen's offsets cannot take."""
    if min_steps is None:
        min_steps = min(MIN_SUBTASK_STEPS, int(MIN_SUBTASK_SHARE * float(np.median(lengths))))
    order, bounds = list(plan.order), [list(b) for b in plan.boundaries]
    merged = list(plan.merged)

    def durations() -> np.ndarray:  # (demonstrations, sub-tasks)
        return np.array([np.diff([0, *b, n]) for b, n in zip(bounds, lengths, strict=True)])

    while len(order) > 1:
        median = np.median(durations(), axis=0)
        i = int(np.argmin(median))
        if median[i] >= min_steps:
            break
        cut = i if i < len(order) - 1 else i - 1  # the boundary between sub-task `cut` and the next goes
        merged.append(order.pop(cut))
        for b in bounds:
            del b[cut]
    short = tuple((d, i, int(n)) for d, row in enumerate(durations()) for i, n in enumerate(row)
                  if n < min_steps and len(order) > 1)
    return replace(plan, order=tuple(order), boundaries=tuple(tuple(b) for b in bounds),
                   unused=tuple(sorted({*plan.unused, *merged})), merged=tuple(merged), short=short,
                   min_steps=min_steps)


SETTLED = 0.2
"""the fingers move while their speed is at least this share of the demonstration's fastest finger motion"""
IDLE = 10.0
"""a demonstration's fingers move at all only if their top speed is this many times their median speed"""
MOTION_STEPS = 2
"""a finger motion lasts at least this many steps: a one-step jolt (the object knocking the fingers as the arm
lifts) is not one"""
GRASP_LAG = 3
"""a boundary goes to the end of a finger motion that starts in its own sub-task or at most this many steps after
it"""


def finger_motions(speed: np.ndarray) -> list[tuple[int, int]]:
    """The finger motions of one demonstration as (first moving step, first step stopped again), from its fingers'
    speed per step (`SETTLED`, `IDLE`, `MOTION_STEPS`)."""
    top = float(speed.max()) if len(speed) else 0.0
    if top <= 0 or top < IDLE * float(np.median(speed)):
        return []
    moving = np.concatenate([[False], speed >= SETTLED * top, [False]])
    edges = np.flatnonzero(np.diff(moving.astype(np.int8)))
    return [(int(a), int(b)) for a, b in zip(edges[::2], edges[1::2], strict=True)
            if b < len(speed) and b - a >= MOTION_STEPS]


def settle_grasps(plan: SubtaskPlan, finger_speed: Sequence[np.ndarray | None]) -> SubtaskPlan:
    """`plan` with each boundary after a finger motion moved to the step the fingers stopped: MimicGen's grasp
    signal turns 1 when the object is held, and on robosuite's Stack and PickPlaceCan that comes 5-7 steps after
    the command to close, while the codes switch at the command or where the arm next moves (the lift, 7 steps
    after the fingers stopped on Stack, 20-24 on PickPlaceCan). A MimicGen sub-task ends where its object is held
    or let go, so the motion taken is one that starts within the boundary's own sub-task (after the boundary before
    it) or at most `GRASP_LAG` steps after it, the one whose end is nearest; the boundary stays where it was
    without one, or when moving it would reach a neighbouring boundary (each sub-task keeps a step, the last two).
    `finger_speed`: per demonstration, the fingers' speed at every step, or None (no gripper velocities in the
    observations: nothing moves)."""
    moved = 0
    boundaries = []
    for cuts, speed in zip(plan.boundaries, finger_speed, strict=True):
        new = list(cuts)
        motions = finger_motions(speed) if speed is not None else []
        for j, b in enumerate(cuts):
            first = new[j - 1] if j > 0 else 0
            near = [end for start, end in motions if first <= start <= b + GRASP_LAG]
            if not near:
                continue
            to = min(near, key=lambda end: (abs(end - b), end))
            low = new[j - 1] + 1 if j > 0 else 1
            high = (cuts[j + 1] - 1) if j + 1 < len(cuts) else len(speed) - 2  # type: ignore[arg-type]
            if to != b and low <= to <= high:
                new[j] = to
                moved += 1
        boundaries.append(tuple(new))
    return replace(plan, boundaries=tuple(boundaries), settled=plan.settled + moved)
