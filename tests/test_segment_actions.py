"""The start's model of continuous actions (`segment_models._ActionKinds`, `VAEConfig.init_actions`): clipped
dimensions scored only up to their bound, few-valued dimensions (a gripper) by a softmax over their values, and
the start merged down from more codes (`segment_init._merged_down`)."""

from __future__ import annotations

import numpy as np
import pytest

from digail.algos.segment_init import hard_em_segmentation
from digail.algos.segment_models import _ActionKinds, _design, _LinearPolicies
from digail.data.minari_io import load_dataset
from digail.envs.metaworld import merge_short_runs
from digail.eval.segmentation import segmentation_metrics


def test_kinds_are_read_off_the_actions() -> None:
    rng = np.random.default_rng(0)
    smooth = rng.normal(0, 0.3, 1000)
    clipped = np.clip(rng.normal(0, 2, 1000), -1, 1)  # about 60% at a bound
    gripper = np.where(np.arange(1000) < 400, -1.0, 0.6)
    a = np.c_[smooth, clipped, gripper]
    kinds = _ActionKinds(a)
    assert np.isinf(kinds.lo[0]) and np.isinf(kinds.hi[0])
    assert kinds.lo[1] == -1 and kinds.hi[1] == 1
    assert set(kinds.values) == {2} and kinds.values[2].tolist() == [-1.0, 0.6]
    assert kinds.gaussian.tolist() == [True, True, False]
    np.testing.assert_array_equal(kinds.index(a[398:402], 2), [0, 0, 1, 1])


def test_a_clipped_step_costs_nothing_past_its_bound() -> None:
    a = np.array([[1.0], [1.0], [0.2], [-1.0]] * 10)
    kinds = _ActionKinds(a)
    pred = np.array([[1.7], [0.6], [0.5], [-3.0]] * 10)
    np.testing.assert_allclose(kinds.residual(a, pred)[:4, 0], [0.0, 0.4, -0.3, 0.0])


def test_censored_fit_recovers_a_saturating_controller() -> None:
    """a = clip(10 (g - x)): least squares bends the gain towards the saturated steps, the censored fit does not."""
    x = np.linspace(-1, 1, 400)[:, None]
    a = np.clip(10 * (0.3 - x), -1, 1)
    feats = np.c_[x, np.ones(len(x))]
    plain = _LinearPolicies(1, 2, 1, False, ridge=1e-6, actions="gaussian")
    plain.fit(feats, a, np.zeros(len(x), np.int64))
    censored = _LinearPolicies(1, 2, 1, False, ridge=1e-6, actions="auto")
    censored.fit(feats, a, np.zeros(len(x), np.int64))
    assert abs(censored.w[0, 0, 0] + 10) < 1.0 and abs(censored.w[0, 1, 0] - 3) < 0.3
    assert abs(plain.w[0, 0, 0] + 10) > 5


@pytest.fixture(scope="module")
def pick_place() -> list:
    import dataclasses

    trajs = load_dataset("digail/metaworld-pick-place/expert-v0").trajs[:24]
    return [dataclasses.replace(t, subtasks=merge_short_runs(np.asarray(t.subtasks))) for t in trajs]


@pytest.mark.slow
def test_pick_place_phases_need_the_gripper_as_a_command(pick_place: list) -> None:
    """Meta-World's pick-place expert: its gripper closes inside the descent, not where a phase ends. As a Gaussian
    the gripper bought codes of its own (reach merged with descend); as a few-valued command it does not."""
    labels = [t.subtasks for t in pick_place]
    new = segmentation_metrics(hard_em_segmentation(pick_place, 4, False, seed=0, ridge=1e-4), labels)
    old = segmentation_metrics(hard_em_segmentation(pick_place, 4, False, seed=0, ridge=1e-4, actions="gaussian"),
                               labels)
    assert new["accuracy"] >= 0.85, new
    assert old["accuracy"] < new["accuracy"] - 0.1, (old, new)


def test_design_keeps_the_actions_as_recorded(pick_place: list) -> None:
    _, a, n, _, _ = _design(pick_place, False)
    kinds = _ActionKinds(a)
    assert n == 4 and 3 in kinds.values and np.isfinite(kinds.hi[:3]).any()
