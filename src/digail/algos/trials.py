"""Choices made in the simulator before generating: each sub-task's frame (`trial_frames`) and the source every
attempt replays (`trial_sources`). With a few source demonstrations, what the demonstrations say (three end poses
for a frame, nothing at all for which source moves well into new scenes) is weaker evidence than a few attempts, and
attempts are what generation pays for anyway; the trials play on scenes of their own (reset seeds after the
attempts'), and their env steps are returned so that the cost is counted."""

from __future__ import annotations

import dataclasses
import itertools
from collections.abc import Callable
from typing import Any

from digail.algos.frames import Frame, frame_names
from digail.algos.generate import GenerationPlan, replay, source_for

SEARCH_ALL_MAX = 256
"""`trial_frames` tries every frame assignment (when its start fails everywhere) only up to this many of them"""
SEARCH_ALL_SCENES = 3
"""scenes each assignment is tried on in that search"""


def _wins(plan: GenerationPlan, env: Any, sources: list[int], frames: dict[int, Frame], seed: int,
          bar: Any) -> tuple[int, int]:
    """Successes and env steps of `plan` in `frames` on the scenes reset with `seed` on, scene i replaying
    `sources[i]`."""
    wins = steps = 0
    for i, src in enumerate(sources):
        result = replay(plan, env, src, frames, seed + i)
        wins += result.success
        steps += result.steps
        bar.update(1)
    return wins, steps


def trial_frames(plan: GenerationPlan, make_env: Callable[[], Any], trials: int, seed: int, *,
                 progress: bool = True) -> tuple[dict[int, Frame], list[dict[str, Any]], int]:
    """Frames chosen by trying them in the simulator: from `plan.frames`, each sub-task in turn (by key) takes every
    other frame the scene has, on the same `trials` scenes (reset seeds `seed` on), and keeps the one whose attempts
    succeed most often (the current one on a tie). With a few sources the most consistent end pose can name the
    wrong frame (three end poses decide it); attempts are what generation pays for anyway.

    Where no attempt of `plan.frames` succeeds (two sub-tasks wrong at once leave every single change failing too),
    the search starts instead from the assignment that succeeds most often on the first `SEARCH_ALL_SCENES` scenes
    among all of them, when there are at most `SEARCH_ALL_MAX`.

    Returns:
        `(frames, record, env_steps)`: the chosen frames, one entry per assignment tried (its frames and its
        successes) and the env steps the trials took.
    """
    from digail.utils import progress_bar

    keys = sorted(plan.frames)
    names = frame_names(plan.scene)
    bar = progress_bar(trials * (1 + len(keys) * (len(names) - 1)), progress, desc="frames", unit="attempt")
    env = make_env()
    steps = 0
    sources = [source_for(plan, env, i, seed + i) for i in range(trials)]

    def score(frames: dict[int, Frame], scenes: int = trials) -> int:
        nonlocal steps
        wins, used = _wins(plan, env, sources[:scenes], frames, seed, bar)
        steps += used
        return wins

    def entry(frames: dict[int, Frame], wins: int, scenes: int = trials) -> dict[str, Any]:
        return {"frames": {str(k): v for k, v in sorted(frames.items())}, "successes": wins,
                **({"scenes": scenes} if scenes != trials else {})}

    try:
        best = dict(plan.frames)
        best_wins = score(best)
        record = [entry(best, best_wins)]
        every = len(names) ** len(keys)
        if best_wins == 0 and every <= SEARCH_ALL_MAX:
            few = min(SEARCH_ALL_SCENES, trials)
            bar.total += every * few + trials
            found, found_wins = None, 0
            for assignment in itertools.product(names, repeat=len(keys)):
                tried = dict(zip(keys, assignment, strict=True))
                wins = score(tried, few)
                record.append(entry(tried, wins, few))
                if wins > found_wins:
                    found, found_wins = tried, wins
            if found is not None:
                best, best_wins = found, score(found)
                record.append(entry(best, best_wins))
        for key in keys:
            for name in names:
                if name == best[key]:
                    continue
                tried = {**best, key: name}
                wins = score(tried)
                record.append(entry(tried, wins))
                if wins > best_wins:
                    best, best_wins = tried, wins
    finally:
        bar.close()
        env.close()
    return best, record, steps


PICK_TRIALS = 20
"""scenes each source is tried on when the source is chosen by trial without frame trials"""


def replaying(plan: GenerationPlan, source: int) -> GenerationPlan:
    """`plan` replaying its source number `source` in every attempt (`pick` `first`, that source moved first; the
    others stay, for the record and the frames)."""
    order = [source] + [i for i in range(len(plan.sources)) if i != source]
    return dataclasses.replace(plan, sources=[plan.sources[i] for i in order],
                               source_ids=[plan.source_ids[i] for i in order],
                               segments=[plan.segments[i] for i in order], pick="first")


def trial_sources(plan: GenerationPlan, make_env: Callable[[], Any], trials: int, seed: int, *,
                  frame_trials: bool = False, progress: bool = True
                  ) -> tuple[GenerationPlan, list[dict[str, Any]], int]:
    """The source every attempt replays, chosen by trying each: each source alone is replayed on the same `trials`
    scenes (reset seeds `seed` on), with its own frames chosen first by `trial_frames` on those scenes when
    `frame_trials`, and the one whose attempts succeed most often is kept (the earlier on a tie). Sources of one
    task differ in how well they move into new scenes far more than frames make them (one grasp holds when the
    object moves, another slips), and one source for every scene is also what a behaviour-cloned policy fits best.

    Returns:
        `(plan, record, env_steps)`: the plan replaying the chosen source (`replaying`, with the frames its trials
        chose), one entry per source (its episode id, frames, successes, and its frame trials when there were any)
        and the env steps all the trials took.
    """
    from digail.utils import progress_bar

    record: list[dict[str, Any]] = []
    steps = 0
    best, best_wins = replaying(plan, 0), -1
    for s in range(len(plan.sources)):
        candidate = replaying(plan, s)
        if frame_trials:
            frames, tried, used = trial_frames(candidate, make_env, trials, seed, progress=progress)
            wins = max(e["successes"] for e in tried if "scenes" not in e)
            candidate = dataclasses.replace(candidate, frames=frames)
            steps += used
        else:
            env, bar = make_env(), progress_bar(trials, progress, desc=f"source {plan.source_ids[s]}", unit="attempt")
            try:
                wins, used = _wins(candidate, env, [0] * trials, candidate.frames, seed, bar)
                steps += used
            finally:
                bar.close()
                env.close()
        record.append({"source": plan.source_ids[s], "successes": wins, "scenes": trials,
                       "frames": {str(k): v for k, v in sorted(candidate.frames.items())},
                       **({"frame_trials": tried} if frame_trials else {})})
        if wins > best_wins:
            best, best_wins = candidate, wins
    return best, record, steps
