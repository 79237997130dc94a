"""Segmentation: causal decoding, Viterbi smoothing, metrics on hand-made cases, the `segment` command."""

from __future__ import annotations

import dataclasses
import json
import sys
import types
from pathlib import Path

import numpy as np
import pytest
import torch

from digail.algos.decode import read_codes, segment, segment_many, segment_offline_many
from digail.checkpoint import save_model
from digail.commands.segment import SegmentArgs, segment_command
from digail.data.trajectory import Trajectory
from digail.errors import UserError
from digail.eval.segmentation import (
    boundary_hits,
    segmentation_metrics,
    switch_points,
    viterbi,
)
from digail.nets.policy import ActionSpec
from digail.nets.vae import HierarchicalPolicy

TWO_PHASE = np.r_[np.zeros(10, np.int64), np.ones(11, np.int64)]  # T + 1 = 21 labels, switch at step 10


# ------------------------------------------------------------------------------------------------ metrics
def test_perfect_codes_score_one() -> None:
    labels = [TWO_PHASE, np.r_[np.zeros(4, np.int64), np.ones(4, np.int64), np.full(5, 2)]]
    codes = [lab[:-1] for lab in labels]
    m = segmentation_metrics(codes, labels)
    assert m["accuracy"] == 1.0 and m["nmi"] == pytest.approx(1.0) and m["boundary_f1"] == 1.0
    assert m["matching"] == "one-to-one" and m["switches_per_episode"] == m["true_switches_per_episode"] == 1.5
    assert m["steps"] == 20 + 12 and m["episodes"] == 2


def test_permuted_codes_score_one_and_report_the_mapping() -> None:
    labels = [np.array([0, 0, 1, 1, 2, 2, 2]), np.array([2, 2, 0, 0, 1, 1, 1])]
    perm = np.array([5, 3, 7])  # label -> code; codes need not be 0..K-1
    codes = [perm[lab[:-1]] for lab in labels]
    m = segmentation_metrics(codes, labels)
    assert m["accuracy"] == 1.0 and m["nmi"] == pytest.approx(1.0)
    assert m["mapping"] == {5: 0, 3: 1, 7: 2}


def test_random_codes_score_low() -> None:
    rng = np.random.default_rng(0)
    labels = [np.repeat(rng.permutation(4), 25) for _ in range(20)]
    codes = [rng.integers(0, 4, 99) for _ in range(20)]
    m = segmentation_metrics(codes, labels)
    assert m["accuracy"] < 0.35 and m["nmi"] < 0.05 and m["boundary_f1"] < 0.2


def test_constant_codes_give_chance_accuracy_and_zero_nmi() -> None:
    m = segmentation_metrics([np.zeros(20, np.int64)], [TWO_PHASE])
    assert m["accuracy"] == 0.5 and m["nmi"] == pytest.approx(0.0, abs=1e-12)
    assert m["boundary_recall"] == 0.0 and m["boundary_precision"] == 1.0 and m["boundary_f1"] == 0.0


def test_many_to_one_when_more_codes_than_labels() -> None:
    codes = [np.r_[np.zeros(5), np.ones(5), np.full(10, 2)].astype(np.int64)]  # codes 0, 1 both mean label 0
    m = segmentation_metrics(codes, [TWO_PHASE])
    assert m["matching"] == "many-to-one" and m["accuracy"] == 1.0
    assert m["mapping"] == {0: 0, 1: 0, 2: 1}
    one_to_one = segmentation_metrics([np.r_[np.zeros(10), np.ones(10)].astype(np.int64)], [TWO_PHASE])
    assert one_to_one["matching"] == "one-to-one"


def test_fewer_codes_than_labels_leave_a_label_unmatched() -> None:
    labels = [np.r_[np.zeros(5), np.ones(5), np.full(6, 2)].astype(np.int64)]
    codes = [np.r_[np.zeros(10), np.ones(5)].astype(np.int64)]
    m = segmentation_metrics(codes, labels)
    assert m["matching"] == "one-to-one" and len(m["mapping"]) == 2 and m["accuracy"] == pytest.approx(10 / 15)


def test_boundary_tolerance() -> None:
    assert list(switch_points(np.array([0, 0, 1, 1, 0]))) == [2, 4]
    assert boundary_hits(np.array([12]), np.array([10]), tolerance=2) == 1
    assert boundary_hits(np.array([13]), np.array([10]), tolerance=2) == 0
    assert boundary_hits(np.array([8]), np.array([10]), tolerance=2) == 1
    # each true switch is matched once: two predictions next to one true switch give one hit
    assert boundary_hits(np.array([9, 11]), np.array([10]), tolerance=2) == 1
    # greedy in time order finds the full matching here
    assert boundary_hits(np.array([9, 11]), np.array([8, 12]), tolerance=1) == 2

    late = np.r_[np.zeros(12), np.ones(8)].astype(np.int64)  # switch at 12, true one at 10
    assert segmentation_metrics([late], [TWO_PHASE])["boundary_f1"] == 1.0
    assert segmentation_metrics([late], [TWO_PHASE], tolerance=1)["boundary_f1"] == 0.0
    chatter = np.r_[np.zeros(10), np.ones(3), np.zeros(2), np.ones(5)].astype(np.int64)  # 3 switches, 1 hit
    m = segmentation_metrics([chatter], [TWO_PHASE])
    assert m["boundary_precision"] == pytest.approx(1 / 3) and m["boundary_recall"] == 1.0
    assert m["boundary_f1"] == pytest.approx(0.5) and m["switches_per_episode"] == 3


def test_no_switches_anywhere_is_a_perfect_boundary_score() -> None:
    m = segmentation_metrics([np.zeros(6, np.int64)], [np.ones(7, np.int64)])
    assert m["boundary_f1"] == 1.0 and m["accuracy"] == 1.0
    spurious = segmentation_metrics([np.array([0, 0, 1, 1, 1, 1])], [np.ones(7, np.int64)])
    assert spurious["boundary_recall"] == 1.0 and spurious["boundary_precision"] == 0.0
    assert spurious["boundary_f1"] == 0.0


def test_metrics_reject_mismatched_inputs() -> None:
    with pytest.raises(ValueError, match="episodes"):
        segmentation_metrics([np.zeros(3, np.int64)], [])
    with pytest.raises(ValueError, match="labels"):
        segmentation_metrics([np.zeros(5, np.int64)], [np.zeros(3, np.int64)])


# ----------------------------------------------------------------------------------------------- decoding
def _switching_model() -> HierarchicalPolicy:
    """q keeps code 0 until x > 0.5, then code 1 forever (it remembers through the previous code)."""
    model = HierarchicalPolicy(2, 2, ActionSpec(False, 2), hidden=(4,))
    with torch.no_grad():
        first, last = model.q.net[0], model.q.net[-1]
        first.weight.zero_()
        first.bias.zero_()
        first.weight[0, 0] = 10.0  # unit 0: x
        first.bias[0] = -5.0  # active when x > 0.5
        first.weight[1, 3] = 10.0  # unit 1: previous code was 1
        last.weight.zero_()
        last.bias.copy_(torch.tensor([1.0, 0.0]))
        last.weight[1, 0] = 10.0
        last.weight[1, 1] = 10.0
    return model


def _walk(xs: np.ndarray) -> Trajectory:
    obs = np.stack([xs, np.zeros_like(xs)], 1).astype(np.float32)
    return Trajectory(obs, np.zeros((len(xs) - 1, 2), np.float32))


def test_causal_decoding_uses_the_previous_code() -> None:
    model = _switching_model()
    traj = _walk(np.array([0.0, 0.2, 0.7, 0.3, 0.1, 0.0]))  # crosses 0.5 once, then comes back
    np.testing.assert_array_equal(segment(model, traj), [0, 0, 1, 1, 1])
    short = _walk(np.array([0.0, 0.9, 0.0]))
    batched = segment_many(model, [traj, short])
    np.testing.assert_array_equal(batched[0], [0, 0, 1, 1, 1])
    np.testing.assert_array_equal(batched[1], segment(model, short))
    assert segment_many(model, []) == []


def test_viterbi_follows_the_decoder_and_the_prior() -> None:
    """Decoder: code 0 moves right, code 1 moves left; a sticky prior smooths out one odd action."""
    model = HierarchicalPolicy(1, 2, ActionSpec(False, 1), hidden=(4,))
    with torch.no_grad():
        for p in model.pi.parameters():
            p.zero_()
        last = model.pi.net[-1]
        first = model.pi.net[0]
        first.weight[0, 1] = 1.0  # hidden unit 0 = [code 0]
        first.weight[1, 2] = 1.0  # hidden unit 1 = [code 1]
        last.weight[0, 0], last.weight[0, 1] = 1.0, -1.0  # mean +1 for code 0, -1 for code 1
        model.pi.log_std.fill_(0.0)
        model.prior.table.copy_(torch.tensor([[3.0, -3.0], [-3.0, 3.0], [0.0, 0.0]]))
    acts = np.array([1, 1, 1, -1, 1, 1, -1, -1, -1, -1], np.float32)[:, None]
    traj = Trajectory(np.zeros((11, 1), np.float32), acts)
    np.testing.assert_array_equal(viterbi(model, traj), [0] * 6 + [1] * 4)
    with torch.no_grad():
        model.prior.table.zero_()  # no preference for staying: every action decides its own code
    np.testing.assert_array_equal(viterbi(model, traj), [0, 0, 0, 1, 0, 0, 1, 1, 1, 1])


def _left_right_model(sticky: float) -> HierarchicalPolicy:
    """pi: code 0 moves right (+1), code 1 left (-1); q: keeps the previous code with logit `sticky`, whatever the
    state (the start input: no preference)."""
    model = HierarchicalPolicy(1, 2, ActionSpec(False, 1), hidden=(4,))
    with torch.no_grad():
        for p in [*model.pi.parameters(), *model.q.parameters()]:
            p.zero_()
        model.pi.net[0].weight[0, 1] = 1.0  # hidden unit 0 = [code 0]
        model.pi.net[0].weight[1, 2] = 1.0  # hidden unit 1 = [code 1]
        model.pi.net[-1].weight[0, 0], model.pi.net[-1].weight[0, 1] = 1.0, -1.0
        model.pi.log_std.fill_(0.0)
        first, last = model.q.net[0], model.q.net[-1]
        first.weight[0, 1] = 1.0  # hidden unit 0 = [previous code 0]
        first.weight[1, 2] = 1.0  # hidden unit 1 = [previous code 1]
        last.weight[0, 0], last.weight[1, 1] = sticky, sticky
    return model


def test_offline_reading_weighs_the_actions_and_the_macro_policy() -> None:
    acts = np.array([1, 1, 1, -1, 1, 1, -1, -1, -1, -1], np.float32)[:, None]
    traj = Trajectory(np.zeros((11, 1), np.float32), acts)
    # a sticky q outweighs one odd action; the causal reading, blind to the actions, never leaves its first code
    np.testing.assert_array_equal(segment_offline_many(_left_right_model(3.0), [traj])[0], [0] * 6 + [1] * 4)
    # with no preference for staying, every action decides its own code
    np.testing.assert_array_equal(read_codes(_left_right_model(0.0), [traj], "offline")[0],
                                  [0, 0, 0, 1, 0, 0, 1, 1, 1, 1])
    assert len(set(read_codes(_left_right_model(3.0), [traj], "causal")[0].tolist())) == 1
    short = Trajectory(np.zeros((4, 1), np.float32), acts[:3])
    batched = segment_offline_many(_left_right_model(3.0), [traj, short])
    np.testing.assert_array_equal(batched[1], [0, 0, 0])
    with pytest.raises(UserError, match="unknown reading"):
        read_codes(_left_right_model(3.0), [traj], "smoothed")


# ------------------------------------------------------------------------------------------------ command
@dataclasses.dataclass
class _FakeDataset:
    trajs: list[Trajectory]
    env_id: str | None
    dataset_id: str
    metadata: dict = dataclasses.field(default_factory=dict)


def fake_minari(monkeypatch: pytest.MonkeyPatch, trajs: list[Trajectory], env_id: str = "toy/TwoPhase-v0") -> None:
    """Replace the Minari reader with one that returns `trajs` for any dataset name."""
    module = types.ModuleType("digail.data.minari_io")
    module.load_dataset = lambda ref: _FakeDataset(trajs, env_id, "toy/two-phase-v0")  # type: ignore[attr-defined]
    # the dataset's folder and metadata, read before the dataset: a folder named as the dataset, with no record
    module.dataset_metadata = lambda ref: (Path(str(ref)), {})  # type: ignore[attr-defined]
    monkeypatch.setitem(sys.modules, "digail.data.minari_io", module)


def test_segment_command_writes_codes_metrics_and_figure(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    model = _switching_model()
    rng = np.random.default_rng(0)
    trajs = []
    for _ in range(5):
        xs = np.r_[np.linspace(0, 1, 12), np.linspace(0.9, 0, 10)] + rng.normal(0, 0.01, 22)
        traj = _walk(xs)
        trajs.append(Trajectory(traj.obs, traj.acts, None, (xs > 0.5).cumsum().clip(0, 1).astype(np.int64)))
    fake_minari(monkeypatch, trajs)
    run = tmp_path / "run"
    run.mkdir()
    save_model(run / "model.pt", model, kind="vae", config={"demos": "toy"}, env_id="toy/TwoPhase-v0")
    (run / "config.json").write_text(json.dumps({"demos": "toy"}))
    metrics = segment_command(SegmentArgs(run, reading="causal"))
    assert metrics["accuracy"] == 1.0 and metrics["boundary_f1"] == 1.0 and metrics["switches_per_episode"] == 1
    saved = json.loads((run / "segmentation.json").read_text())
    assert saved["accuracy"] == 1.0 and saved["matching"] == "one-to-one" and "viterbi" in saved
    assert saved["reading"] == "causal" and set(saved["readings"]) == {"causal", "offline"}
    assert saved["readings"]["causal"]["accuracy"] == 1.0
    codes = np.load(run / "codes.npz")
    assert len(codes.files) == 5 and codes["episode_00000"].shape == (21,)
    assert (run / "figures" / "segmentation.png").stat().st_size > 1000

    unlabeled = [Trajectory(t.obs, t.acts) for t in trajs]
    fake_minari(monkeypatch, unlabeled)
    metrics = segment_command(SegmentArgs(run, demos="other", reading="causal"))
    assert metrics["labels"] is False and metrics["switches_per_episode"] == 1.0

    fake_minari(monkeypatch, trajs, env_id="digail/CircleWorld-v0")
    with pytest.raises(UserError, match="trained on"):
        segment_command(SegmentArgs(run))
    with pytest.raises(UserError, match="does not exist"):
        segment_command(SegmentArgs(tmp_path / "nowhere"))


def test_composed_schedules_follow_the_segmentations_code_matching() -> None:
    from digail.envs.registry import ENV_SPECS
    from digail.eval.composition import schedule_in_codes

    reversed_circles = ENV_SPECS["digail/CircleWorld-v0"].compose_schedule
    assert schedule_in_codes(reversed_circles, {"0": 0, "1": 1}) == "1:60,0:60"
    assert schedule_in_codes(reversed_circles, {"0": 1, "1": 0}) == "0:60,1:60"
    assert schedule_in_codes(reversed_circles, {"0": 0, "1": 0}) is None  # collapsed: no counter-clockwise code


def test_label_map_merges_oracle_labels_before_scoring() -> None:
    from digail.eval.segmentation import merge_labels

    phases = np.array([0, 0, 1, 1, 2, 2, 3, 3])
    merged = merge_labels(phases, (0, 0, 1, 1))
    np.testing.assert_array_equal(merged, [0, 0, 0, 0, 1, 1, 1, 1])
    codes = [np.array([1, 1, 1, 1, 0, 0, 0, 0])]
    scores = segmentation_metrics(codes, [merged])
    assert scores["accuracy"] == 1.0 and scores["true_switches_per_episode"] == 1.0
    assert scores["boundary_f1"] == 1.0
    with pytest.raises(ValueError, match="label map"):
        merge_labels(phases, (0, 1))
