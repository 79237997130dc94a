"""Property-based tests (hypothesis): the schedule parser and `Trajectory` validation."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from digail.data.trajectory import Trajectory
from digail.errors import UserError
from digail.eval.composition import CodeSchedule, parse_schedule

SETTINGS = settings(max_examples=60, deadline=None)

pairs_st = st.lists(st.tuples(st.integers(0, 9), st.integers(1, 80)), min_size=1, max_size=8)
space = st.sampled_from(["", " ", "  "])


@SETTINGS
@given(pairs=pairs_st, codes=st.integers(1, 10), limit=st.one_of(st.none(), st.integers(1, 400)),
       pads=st.lists(space, min_size=32, max_size=32))
def test_schedule_parses_to_pairs_or_refuses(pairs, codes, limit, pads):
    """Well-formed text gives exactly its pairs, unless a code is out of range or the total passes the limit."""
    text = ",".join(f"{pads[2 * i % 32]}{c}{pads[(2 * i + 1) % 32]}:{n}" for i, (c, n) in enumerate(pairs))
    total = sum(n for _, n in pairs)
    ok = all(c < codes for c, _ in pairs) and total <= (limit if limit is not None else 10**6)
    if ok:
        assert parse_schedule(text, codes, limit) == pairs
    else:
        with pytest.raises(UserError):
            parse_schedule(text, codes, limit)


@SETTINGS
@given(pairs=pairs_st)
def test_code_schedule_matches_the_expanded_list(pairs):
    expanded = [c for c, n in pairs for _ in range(n)]
    sched = CodeSchedule(pairs)
    assert len(sched) == len(expanded)
    assert list(sched) == expanded
    assert sched[-1] == expanded[-1]


@SETTINGS
@given(text=st.text(max_size=60), codes=st.integers(1, 8), limit=st.one_of(st.none(), st.integers(1, 10**4)))
def test_any_text_gives_pairs_or_one_user_error(text, codes, limit):
    """Whatever the text, the parser returns bounded pairs or raises `UserError`, never anything else."""
    try:
        pairs = parse_schedule(text, codes, limit)
    except UserError as exc:
        assert "\n" not in str(exc)
    else:
        assert pairs and all(0 <= c < codes and n >= 1 for c, n in pairs)
        assert sum(n for _, n in pairs) <= (limit if limit is not None else 10**6)


@settings(max_examples=10, deadline=None)
@given(digits=st.integers(10, 5000), code=st.integers(0, 1))
def test_huge_step_counts_are_refused_without_building_anything(digits, code):
    with pytest.raises(UserError, match="longer than"):
        parse_schedule(f"{code}:{'9' * digits}", 2, 120)


@SETTINGS
@given(T=st.integers(0, 6), extra_obs=st.integers(-2, 2), obs_dim=st.integers(1, 3),
       discrete=st.booleans(), bad=st.sampled_from([None, "nan_obs", "inf_act", "rews_len", "sub_len", "sub_float"]),
       seed=st.integers(0, 2**16))
def test_trajectory_exists_only_when_well_formed(T, extra_obs, obs_dim, discrete, bad, seed):
    """A `Trajectory` is built exactly when obs has one more row than acts (at least one transition), every value is
    finite and the optional arrays are aligned; otherwise a `ValueError` says why."""
    rng = np.random.default_rng(seed)
    obs = rng.normal(size=(max(T + extra_obs, 0), obs_dim)).astype(np.float32)
    acts = rng.integers(0, 4, size=T) if discrete else rng.normal(size=(T, 2)).astype(np.float32)
    rews = rng.normal(size=T).astype(np.float32)
    subtasks = rng.integers(0, 3, size=len(obs))
    valid = extra_obs == 1 and T >= 1
    if bad == "nan_obs" and len(obs):
        obs[-1, 0] = np.nan
        valid = False
    if bad == "inf_act" and not discrete and T:
        acts[0, 0] = np.inf
        valid = False
    if bad == "rews_len":
        rews = rews[:-1] if T else np.zeros(1, np.float32)
        valid = False
    if bad == "sub_len":
        subtasks = subtasks[:-1] if len(subtasks) else np.zeros(1, np.int64)
        valid = False
    if bad == "sub_float" and len(subtasks):
        subtasks = subtasks.astype(np.float64)
        valid = False
    if valid:
        traj = Trajectory(obs, acts, rews, subtasks)
        assert len(traj) == T and traj.discrete == discrete
    else:
        with pytest.raises(ValueError):
            Trajectory(obs, acts, rews, subtasks)
