"""Composition: run the learned sub-task policies in an order of the user's instead of the macro-policy's.

Two ways to say the order:

- open loop, a code schedule (`parse_schedule`, `compose`): code:steps pairs, so the user gives every sub-task's
  duration. The paper's reversed-circles experiment: on Circle-World, schedule "1:60,0:60" asks for code 1's
  policy first and code 0's second. Which code learned which circle is arbitrary (`mapping` in the run's
  segmentation.json); with code 1 the counter-clockwise one, this is the order never demonstrated. `digail run`
  translates for you.
- closed loop, a code order (`parse_order`, `compose_order`): codes only; each sub-task policy runs until the
  macro-policy q says its sub-task is over, then the next code of the order takes over (`OrderSwitch` states the
  rule). No durations to guess, but q can only end a sub-task the way the demonstrations ended it.
"""

from __future__ import annotations

import bisect
import itertools
from collections.abc import Sequence
from typing import Any, overload

import numpy as np
import torch

from digail.envs.episodes import BatchAct, Episode, play_batch
from digail.errors import UserError
from digail.eval.returns import run_episodes, summarize
from digail.nets.mlp import one_hot
from digail.nets.vae import HierarchicalPolicy

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


# ------------------------------------------------------------------------------------------ closed loop
DEFAULT_HOLD = 1
"""steps in a row q must say "switch away" before the next code of an order takes over (see `OrderSwitch`)"""


def parse_order(text: str, codes: int) -> list[int]:
    """'2,0,1' -> [2, 0, 1]: the codes a closed-loop composition runs, in turn.

    Raises:
        UserError: one sentence naming what is wrong: nothing given, something that is not a code number, a code
            the policy does not have, or one code twice in a row (its sub-task would end the moment it began).
    """
    parts = [p.strip() for p in str(text).split(",")]
    if not any(parts):
        raise UserError(f"the order is empty; write the codes to run, in turn, such as '1,0' (codes 0 to "
                        f"{codes - 1}).")
    if not all(p.isascii() and p.isdigit() for p in parts):
        raise UserError(f"cannot read the order {text[:60]!r}{'...' if len(text) > 60 else ''}; write code numbers "
                        f"separated by commas, such as '1,0' (codes 0 to {codes - 1}).")
    for p in parts:
        if len(p) > 12 or not int(p) < codes:
            raise UserError(f"the order uses code {p[:12]}{'...' if len(p) > 12 else ''} but the policy has "
                            f"{codes} code{'s' if codes != 1 else ''} (0 to {codes - 1}).")
    order = [int(p) for p in parts]
    for a, b in itertools.pairwise(order):
        if a == b:
            raise UserError(f"the order runs code {a} twice in a row; write it once (its policy runs until the "
                            "macro-policy says its sub-task is over).")
    return order


class OrderSwitch:
    """The closed-loop switching rule of one episode under a code order.

    The current code is `order[i]`, which took over at step `t_i` (0 for the first). At every later step t of its
    turn the macro-policy is asked how likely it is to leave that code: `leave_t = 1 - q(order[i] | s_t,
    c_{t-1} = order[i])`. When the leave probabilities of the turn's last `hold + 1` steps sum to at least
    `hold - 1/2`, the sub-task is over: `order[i + 1]` runs from that step on (step t's action already comes from
    it) and t is noted in `switch_steps`. With probabilities of 0 or 1 this reads "q leaves the code at `hold` of
    the last `hold + 1` steps" (hold 1: at one step; hold 2 ignores a one-step flicker). Which code q would switch
    *to* is ignored; only that it leaves the current one counts, since the user's order, not q, says what comes
    next.

    Why a sum and not q's argmax at single steps: a closed-loop path passes the state where a sub-task ends
    between two steps, so q's leave probability is often split over them (0.47 then 0.21 on Circle-World). An
    argmax then decides on whether one step's share is 0.49 or 0.51, which the CPU's float kernels change (the
    states drift in the last bits over a whole circle), and a missed end costs a whole extra circle. The half step
    of slack in the sum makes such a split end the sub-task at the same step or the next on every machine.
    Wherever the argmax leaves the code, the leave probability is above 1/2, so no end the argmax sees is missed.

    The step a code takes over is never asked: its state is where the previous sub-task (or the episode) ended,
    which q may rightly read as an end (on Circle-World the origin ends the clockwise circle and starts it too).

    A code in `lengths` is a code whose end q never saw (the demonstrations leave it only by ending the episode):
    it runs `lengths[code]` steps instead, its demonstrated length (`demonstrated_lengths`). The last code of the
    order runs until the episode ends; where q says it is over too, the step is noted in `last_over_step`.
    """

    def __init__(self, order: Sequence[int], hold: int = DEFAULT_HOLD, lengths: dict[int, int] | None = None
                 ) -> None:
        if not order or hold < 1:
            raise ValueError(f"OrderSwitch needs a non-empty order and hold >= 1, got {list(order)} and {hold}.")
        self.order = [int(c) for c in order]
        self.hold = int(hold)
        self.lengths = {int(c): int(n) for c, n in (lengths or {}).items()}
        self.index = 0
        self.started = 0
        self._recent: list[float] = []
        """q's leave probabilities at the running code's last steps (at most hold + 1)"""
        self.switch_steps: list[int] = []
        """steps at which the next code of the order took over (one fewer than the order's codes when it ran
        to the end)"""
        self.switch_by: list[str] = []
        """per switch, what ended the sub-task: "q" or "length" (a code in `lengths`)"""
        self.last_over_step: int | None = None
        """first step at which q said the order's last sub-task was over (None: never)"""

    @property
    def current(self) -> int:
        """the code that runs now"""
        return self.order[self.index]

    @property
    def completed(self) -> bool:
        """whether every code of the order took its turn"""
        return self.index == len(self.order) - 1

    def step(self, t: int, leave: float) -> int:
        """The code of step t, given `leave = 1 - q(current | s_t, c_{t-1} = current)`, q's probability of
        leaving the running code at t."""
        if t <= self.started:  # a code's first step is never asked (see the class docstring)
            return self.current
        by = ""
        if self.current in self.lengths and not self.completed:
            by = "length" if t - self.started >= self.lengths[self.current] else ""
        else:
            self._recent = (self._recent + [float(leave)])[-(self.hold + 1):]
            by = "q" if sum(self._recent) >= self.hold - 0.5 else ""
        if by:
            self._recent = []
            if not self.completed:
                self.index += 1
                self.started = int(t)
                self.switch_steps.append(int(t))
                self.switch_by.append(by)
            elif self.last_over_step is None:
                self.last_over_step = int(t)
        return self.current


def demonstrated_lengths(codes: Sequence[np.ndarray]) -> dict[int, int]:
    """The codes whose end q never saw, each with its demonstrated length.

    From the causal codes of the demonstrations (one array per demonstration): a code that every one of its
    segments keeps until the demonstration ends (q never switched away from it) maps to the median length of its
    segments, rounded; codes q did leave somewhere are not listed. Such a code is typically the last sub-task of
    every demonstration (Circle-World's counter-clockwise circle): q can say when it starts, never when it is over.
    """
    ends: dict[int, list[bool]] = {}
    spans: dict[int, list[int]] = {}
    for seq in codes:
        seq = np.asarray(seq).reshape(-1)
        if not len(seq):
            continue
        cuts = np.flatnonzero(np.diff(seq)) + 1
        starts, stops = np.r_[0, cuts], np.r_[cuts, len(seq)]
        for a, b in zip(starts, stops, strict=True):
            ends.setdefault(int(seq[a]), []).append(bool(b < len(seq)))
            spans.setdefault(int(seq[a]), []).append(int(b - a))
    return {c: int(round(float(np.median(spans[c])))) for c in sorted(ends) if not any(ends[c])}


def order_act(model: HierarchicalPolicy, order: Sequence[int], to_env: Any, hold: int = DEFAULT_HOLD,
              lengths: dict[int, int] | None = None, deterministic: bool = True
              ) -> tuple[BatchAct, dict[int, tuple[Episode, OrderSwitch]]]:
    """The model under a closed-loop code order, as a policy for `play_batch`: each episode's codes come from its
    `OrderSwitch` (q, batched over the envs), the actions from pi (its mode when `deterministic`).

    Returns:
        The policy and the table it fills: id(episode) -> (episode, its switch), the episode kept so that its id
        stays unique while the table lives.
    """
    model.eval()
    device = next(model.parameters()).device
    K = model.codes
    eye = torch.eye(K, device=device)
    switches: dict[int, tuple[Episode, OrderSwitch]] = {}

    @torch.no_grad()
    def act(envs: list[Any], obs: list[Any], eps: list[Episode]) -> Any:
        obs_n = model.normalizer(torch.as_tensor(np.stack([np.asarray(o, np.float32) for o in obs]), device=device))
        rules = [switches.setdefault(id(e), (e, OrderSwitch(order, hold, lengths)))[1] for e in eps]
        current = torch.as_tensor([r.current for r in rules], device=device)
        stay = torch.softmax(model.q(obs_n, one_hot(current, K)), -1).gather(1, current[:, None])[:, 0]
        leave = (1.0 - stay).tolist()
        codes = [r.step(e.length, p) for r, e, p in zip(rules, eps, leave, strict=True)]
        for e, c in zip(eps, codes, strict=True):
            e.codes.append(c)
        code_1h = eye[torch.as_tensor(codes, device=device)]
        acts = model.pi.mode(obs_n, code_1h) if deterministic else model.pi.dist(obs_n, code_1h).sample()
        acts_np = acts.cpu().numpy()
        return to_env(acts_np) if to_env is not None else acts_np

    return act, switches


def play_order(model: HierarchicalPolicy, envs: Sequence[Any], order: Sequence[int], episodes: int, seed: int,
               hold: int = DEFAULT_HOLD, lengths: dict[int, int] | None = None, keep_obs: int = 8
               ) -> tuple[list[Episode], list[OrderSwitch]]:
    """`episodes` deterministic episodes (episode e reset with seed + e) on `envs` under the closed-loop `order`;
    returns the episodes and, in the same order, their switches."""
    from digail.envs.actions import env_action_fn

    act, table = order_act(model, order, env_action_fn(envs[0]), hold, lengths)
    eps = play_batch(list(envs), act, episodes, seed, keep=keep_obs)
    return eps, [table[id(e)][1] for e in eps]


def order_summary(switches: Sequence[OrderSwitch]) -> dict[str, Any]:
    """What compose.json records of a closed-loop order: the rule, the switch steps of every episode (and what
    made each), the share of episodes whose order ran to its last code, and when q said the last sub-task was
    over."""
    first = switches[0] if switches else OrderSwitch([0])
    done = [s for s in switches if s.completed]
    per_switch = [float(np.mean([s.switch_steps[i] for s in done])) for i in range(len(first.order) - 1)] \
        if done else []
    return {"order": first.order, "hold": first.hold,
            "rule": f"next code once q's probabilities of leaving the current code, summed over its last "
                    f"{first.hold + 1} steps, reach {first.hold - 0.5:g}, from a code's second step on",
            "demonstrated_lengths": {str(c): n for c, n in first.lengths.items()},
            "order_completed_rate": float(np.mean([s.completed for s in switches])) if switches else 0.0,
            "mean_switch_steps": per_switch,
            "switch_steps": [s.switch_steps for s in switches],
            "switch_by": [s.switch_by for s in switches],
            "last_over_steps": [s.last_over_step for s in switches]}


def compose_order(model: HierarchicalPolicy, env_id: str, order: Sequence[int], episodes: int, seed: int,
                  hold: int = DEFAULT_HOLD, lengths: dict[int, int] | None = None, keep_obs: int = 8,
                  num_envs: int = 8) -> tuple[dict[str, Any], list[Episode]]:
    """Roll out under the closed-loop code `order` (see `OrderSwitch`); returns the summary (the env's task
    metrics and `order_summary`) and the episodes (the first `keep_obs` keep observations)."""
    from digail.envs import make_env

    envs = [make_env(env_id) for _ in range(max(min(num_envs, episodes), 1))]
    try:
        eps, switches = play_order(model, envs, order, episodes, seed, hold, lengths, keep_obs)
    finally:
        for env in envs:
            env.close()
    out = summarize(eps, env_id)
    out.update(env_id=env_id, seed=seed, **order_summary(switches))
    return out, eps
