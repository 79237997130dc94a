"""The rule the robomimic export follows so that MimicGen's source-dataset parser accepts it whatever the
segmentation: one boundary per named sub-task in every demonstration, in one order (digail.data.robomimic)."""

from __future__ import annotations

from pathlib import Path

import h5py
import numpy as np
import pytest

from digail.data.annotations import export_segmentation
from digail.data.importers import read_demonstrations
from digail.data.robomimic import SIGNALS_PATH
from digail.data.subtask_plan import plan_line, plan_signals, plan_subtasks, term_signals
from digail.errors import UserError

FIXTURES = Path(__file__).resolve().parent / "data" / "formats"


def mimicgen_ends(signals: dict[str, np.ndarray], spec: list[str | None], n_steps: int) -> list[int]:
    """MimicGen's parse_source_dataset rule (NVlabs/mimicgen 72bd767), rewritten here: sub-task i ends one step
    after the first 0 -> 1 of its signal at or after the previous sub-task's end; the last one at the end. Raises
    AssertionError where MimicGen's parser does."""
    ends, prev = [], 0
    for name in spec:
        if name is None:
            end = n_steps
        else:
            diffs = signals[name][1:] - signals[name][:-1]
            first = next((int(nz) + 1 for nz in diffs.nonzero()[0] if int(nz) + 1 >= prev), None)
            assert first is not None, f"No valid subtask termination found for {name}"
            end = first + 1
        ends.append(end)
        prev = end
    for a, b in zip(ends, ends[1:], strict=False):  # the sanity check with zero offsets
        assert a < b, f"sub-task ends {a} then {b}"
    return ends


def random_codes(rng: np.random.Generator, n_codes: int) -> list[np.ndarray]:
    """Segmentations as a VAE gives them on bad days: codes that recur, flicker, are missing, out of order."""
    demos = []
    for _ in range(12):
        length = int(rng.integers(6, 40))
        runs = rng.integers(0, n_codes, size=int(rng.integers(1, 8)))
        cuts = np.sort(rng.choice(np.arange(1, length), size=min(len(runs) - 1, length - 1), replace=False))
        demos.append(np.repeat(runs[:len(cuts) + 1], np.diff(np.concatenate([[0], cuts, [length]]))))
    return demos


@pytest.mark.parametrize("seed", range(6))
def test_every_demonstration_gets_one_boundary_per_subtask_mimicgen_parses(seed):
    rng = np.random.default_rng(seed)
    n_codes = int(rng.integers(2, 6))
    codes = random_codes(rng, n_codes)
    plan = plan_subtasks(codes, n_codes)
    names = [f"s{k}" for k in range(n_codes)]
    spec = [*[names[k] for k in plan.order[:-1]], None]
    for i, c in enumerate(codes):
        assert len(plan.boundaries[i]) == len(plan.order) - 1
        signals = dict(zip(names, plan_signals(plan, i, len(c), n_codes), strict=True))
        for k in plan.order[:-1]:  # one 0 -> 1 step each, monotone
            assert signals[names[k]][0] == 0 and np.all(np.diff(signals[names[k]]) >= 0)
        ends = mimicgen_ends(signals, spec, len(c))
        assert ends == [b + 1 for b in plan.boundaries[i]] + [len(c)]


def test_recurring_codes_get_the_boundary_agreeing_with_most_steps():
    codes = [np.array([0, 0, 1, 0, 1, 1, 2, 2]),   # flicker: 2 and 4 agree equally, the earlier wins
             np.array([0, 0, 0, 1, 1, 2, 2, 2, 1, 2]),  # a late relapse of 1 changes nothing
             np.array([0, 0, 0, 0, 0, 2, 2, 2]),   # 1 missing: one step of it, at the earliest
             np.array([0, 0, 0, 1, 1, 1, 2, 2])]   # as coded: its runs' ends
    plan = plan_subtasks(codes, 3)
    assert plan.order == (0, 1, 2) and plan.unused == ()
    assert plan.boundaries == ((2, 6), (3, 5), (4, 5), (3, 6))
    assert plan.refitted == 3


def test_order_is_the_demonstrated_one_and_rare_codes_are_dropped():
    # code 2 comes first in every demonstration, code 3 only in one
    codes = [np.array([2, 2, 0, 0, 1, 1]), np.array([2, 0, 0, 0, 1, 1, 1]), np.array([2, 2, 2, 0, 3, 1])]
    plan = plan_subtasks(codes, 4)
    assert plan.order == (2, 0, 1) and plan.unused == (3,)
    line = plan_line(plan, ["grasp", "place", "reach", "x"])
    assert line.startswith("MimicGen sub-tasks in the demonstrated order: reach, grasp, place (task spec signals: "
                           "reach, grasp, None)")
    assert "1 of 3 demonstrations" in line and "x (in fewer than half" in line and "\n" not in line


def test_codes_that_run_once_keep_their_ends():
    codes = np.array([1, 1, 1, 0, 0, 2, 2, 2])
    sig = term_signals(codes, len(codes), 4)
    np.testing.assert_array_equal(sig[1], np.arange(8) >= 3)
    np.testing.assert_array_equal(sig[0], np.arange(8) >= 5)
    assert not sig[2].any() and not sig[3].any()


def test_too_short_a_demonstration_is_one_sentence():
    with pytest.raises(UserError) as exc:
        plan_subtasks([np.array([0, 1, 2, 2]), np.array([0, 1, 2])], 3, keys=["demo_0", "demo_1"])
    msg = str(exc.value)
    assert msg.startswith("demo_1 has 3 steps") and "segment with fewer codes" in msg and "\n" not in msg
    # one sub-task has nothing to cut: a one-step demonstration is fine
    plan = plan_subtasks([np.array([0]), np.array([0, 0])], 2)
    assert plan.order == (0,) and plan.boundaries == ((), ()) and plan.unused == (1,)


def test_export_writes_the_plan_and_says_it(tmp_path):
    source = FIXTURES / "robomimic_robosuite.hdf5"
    im = read_demonstrations(source)
    # recurring codes in one demonstration, the other two coded once each
    codes = [np.where(np.arange(len(t)) < 5, 0, 1) for t in im.trajs]
    codes[1] = codes[1].copy()
    codes[1][8:10] = 0
    notes: list[str] = []
    out = export_segmentation("robomimic", tmp_path / "a.hdf5", im.episode_keys, codes, ["reach", "carry"],
                              source=im.source, notes=notes)
    assert len(notes) == 1 and notes[0].startswith("MimicGen sub-tasks in the demonstrated order: reach, carry")
    assert "1 of 3 demonstrations" in notes[0]
    with h5py.File(out, "r") as f:
        for key in im.episode_keys:
            signal = f[f"data/{key}/{SIGNALS_PATH}/reach"][()]
            assert mimicgen_ends({"reach": signal}, ["reach", None], len(signal))[0] == 6


def test_names_follow_the_demonstrated_order_whatever_the_code_numbers():
    """`--names reach carry place` names the sub-task the demonstrations take first "reach", whichever code number
    the training gave it; a rarer code comes after the common ones and a code never taken last."""
    from digail.data.subtask_plan import demonstrated_order, names_by_code

    # code 2 first, then code 0, then code 3; code 1 in one demonstration of three only
    codes = [np.repeat([2, 0, 3], [5, 5, 5]), np.repeat([2, 0, 1, 3], [4, 6, 2, 5]), np.repeat([2, 0, 3], [6, 3, 6])]
    assert demonstrated_order(codes, 5) == [2, 0, 3, 1, 4]
    names = names_by_code(["reach", "carry", "place", "regrasp", "never"], codes)
    assert names == ["carry", "regrasp", "reach", "place", "never"]
    plan = plan_subtasks(codes, 5)
    assert plan_line(plan, names).startswith("MimicGen sub-tasks in the demonstrated order: reach, carry, place ")


def test_a_boundary_near_a_grasp_moves_to_where_the_fingers_stop():
    """robosuite's Stack demonstration 0: the gripper is commanded closed at step 33 and its fingers move until
    step 39, where MimicGen's grasp signal turns 1. A boundary at the command (33), at the lift seven steps after
    the fingers stopped (46), or later in the carry (67, as on PickPlaceCan) moves to 39; a boundary whose
    sub-task starts after the motion stays, and so does one whose move would pass the next boundary, and the
    boundaries of a demonstration whose fingers never move. A one-step jolt of the fingers is not a motion."""
    from digail.data.subtask_plan import finger_motions, settle_grasps

    speed = np.full(90, 0.0004)
    speed[34:39] = [0.019, 0.0406, 0.053, 0.0597, 0.0639]
    speed[39] = 0.0091
    assert finger_motions(speed) == [(34, 39)] and finger_motions(np.full(90, 0.0004)) == []
    jolt = speed.copy()
    jolt[60] = 0.04  # one step of the fingers knocked as the arm lifts (held-out PickPlaceCan): no motion
    assert finger_motions(jolt) == [(34, 39)]
    for first in (33, 46, 67):
        codes = [np.repeat([0, 1, 2], [first, 75 - first, 15])] * 3
        plan = plan_subtasks(codes, 3)
        assert plan.boundaries[0] == (first, 75)
        settled = settle_grasps(plan, [speed, np.full(90, 0.0004), None])
        assert settled.boundaries == ((39, 75), (first, 75), (first, 75)) and settled.settled == 1
        assert settle_grasps(plan, [jolt, jolt, jolt]).boundaries == ((39, 75),) * 3
        assert "1 boundaries moved" in plan_line(settled, ["a", "b", "c"])
    # the next sub-task starts at 37: 33 cannot pass it, and 37, as near the motion, goes to 39 instead
    crowded = plan_subtasks([np.repeat([0, 1, 2], [33, 4, 53])], 3)
    assert settle_grasps(crowded, [speed]).boundaries == ((33, 39),)


def test_sub_tasks_too_short_for_mimicgens_offsets_merge_into_the_next():
    """Stack's default export cut the reach into pieces of about 9 and 10 steps before the grasp; MimicGen's offsets
    (up to 20 steps) cannot take them, so they merge into the sub-task after them and their codes' signals stay
    zero. A demonstration whose merged sub-tasks are still short is listed; the last sub-task merges backwards."""
    from digail.data.subtask_plan import merge_short

    codes = [np.repeat([0, 1, 2, 3], [9, 10, 30, 60]), np.repeat([0, 1, 2, 3], [8, 12, 25, 55]),
             np.repeat([0, 1, 2, 3], [10, 9, 5, 70])]
    plan = merge_short(plan_subtasks(codes, 4), [len(c) for c in codes], min_steps=20)
    assert plan.order == (2, 3) and plan.merged == (0, 1) and set(plan.unused) == {0, 1}
    assert plan.boundaries == ((49,), (45,), (24,))
    assert plan.short == ()  # demonstration 2's first sub-task, 24 steps, is long enough
    assert plan_signals(plan, 0, len(codes[0]), 4)[0].sum() == 0
    line = plan_line(plan, [f"code_{k}" for k in range(4)])
    assert "code_0, code_1 (sub-tasks of a median under 20 steps) merged" in line
    tail = merge_short(plan_subtasks([np.repeat([0, 1], [50, 5])] * 2, 2), [55, 55], min_steps=20)
    assert tail.order == (1,) and tail.boundaries == ((), ())  # the short last sub-task merged into the first
    long = merge_short(plan_subtasks(codes, 4), [len(c) for c in codes], min_steps=5)
    assert long.order == (0, 1, 2, 3) and long.merged == ()
    listed = merge_short(plan_subtasks([np.repeat([0, 1], [50, 60]), np.repeat([0, 1], [8, 60]),
                                        np.repeat([0, 1], [40, 60])], 2), [110, 68, 100])
    assert listed.order == (0, 1) and listed.short == ((1, 0, 8),) and listed.min_steps == 10  # a tenth of 100
    tiny = [np.repeat([0, 1, 2], [3, 3, 4])] * 2  # 10-step demonstrations keep their 3-step sub-tasks
    assert merge_short(plan_subtasks(tiny, 3), [10, 10]).order == (0, 1, 2)


def test_the_benchmarks_offsets_check_is_mimicgens():
    """MimicGen's sanity check: end of sub-task i + its largest offset < end of sub-task i + 1 + its smallest; the
    last sub-task ends with the demonstration and takes no offset."""
    from conftest import repo_module

    check = repo_module("benchmarks/robosuite_mimicgen.py").offsets_check
    assert check([40], 110, (10, 20)) and not check([40], 60, (10, 20))  # 40 + 20 < 60 fails
    assert not check([9, 16, 40], 110, (10, 20))  # 9 + 20 < 16 + 10 fails
    assert check([16, 40], 110, (10, 20)) and not check([16, 26], 110, (10, 20))
