"""The peer segmenters of benchmarks/segmentation_peers.py on a tiny two-phase data set, its resumable runs and the
table that merges its rows with digail's. The peers need the `bench` extra; without it those tests skip."""

from __future__ import annotations

import json
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest
from conftest import repo_module

from digail.data.trajectory import Trajectory

peers = repo_module("benchmarks/segmentation_peers.py")


def two_phase(episodes: int = 8, seed: int = 0) -> list[Trajectory]:
    """Episodes of 30-50 steps: move right (phase 0) until a random switch, then up (phase 1), small noise."""
    rng = np.random.default_rng(seed)
    trajs = []
    for _ in range(episodes):
        steps = int(rng.integers(30, 51))
        switch = int(rng.integers(10, steps - 10))
        labels = (np.arange(steps + 1) >= switch).astype(np.int64)
        acts = np.where(labels[:steps, None] == 0, [1.0, 0.0], [0.0, 1.0]) + 0.05 * rng.standard_normal((steps, 2))
        obs = np.vstack([np.zeros((1, 2)), np.cumsum(acts, 0)])
        trajs.append(Trajectory(obs=obs.astype(np.float32), acts=acts.astype(np.float32), subtasks=labels))
    return trajs


@pytest.mark.parametrize("peer", ["hmm-actions", "hmm-states-actions"])
def test_gaussian_hmm_finds_the_two_phases(peer: str) -> None:
    pytest.importorskip("hmmlearn")
    row = peers.run_peer(peer, two_phase(), codes=2, seed=0)
    assert row["accuracy"] >= 0.95
    assert row["boundary_f1_5"] >= 0.9
    assert set(peers.KEYS) <= set(row)


def test_kernel_cpd_is_told_each_episodes_segment_count() -> None:
    pytest.importorskip("ruptures")
    trajs = two_phase()
    row = peers.run_peer("kernel-cpd-told", trajs, codes=2, seed=0)
    assert row["accuracy"] >= 0.95
    # told one switch per episode, it cuts exactly once per episode
    assert row["switches_per_episode"] == row["true_switches_per_episode"] == 1.0


@pytest.mark.slow  # about a minute: JAX compiles dynamax's EM first
def test_linear_regression_hmm_finds_the_two_phases() -> None:
    pytest.importorskip("dynamax")
    trajs = two_phase()
    acts, states = peers.features(trajs)
    codes = peers.linreg_hmm(acts, states, 2, seed=0, restarts=1)
    assert [len(c) for c in codes] == [len(t.acts) for t in trajs]
    assert peers.score(codes, [t.subtasks for t in trajs])["accuracy"] >= 0.95


def test_standardise_drops_constant_dimensions() -> None:
    parts = peers.standardise([np.array([[1.0, 5.0], [3.0, 5.0]]), np.array([[2.0, 5.0]])])
    assert [p.shape for p in parts] == [(2, 1), (1, 1)]
    flat = np.concatenate(parts)
    assert flat.mean() == pytest.approx(0.0) and flat.std() == pytest.approx(1.0)


def test_segment_counts_are_the_label_runs() -> None:
    assert peers.segment_counts([np.array([0, 0, 1, 1, 0]), np.array([2, 2])]) == [3, 1]


def peer_rows(accuracy: dict[str, float]) -> dict:
    return {p: {"seeds": [], "median": {"accuracy": a}} for p, a in accuracy.items()}


def test_table_merges_digail_with_the_peers_and_says_who_was_told() -> None:
    ours = {"tasks": {"metaworld-a": {"median": {"accuracy": 0.70}}, "metaworld-b": {"median": {"accuracy": 0.90}}}}
    theirs = {"tasks": {
        "metaworld-a": {"codes": 4, "peers": peer_rows({"hmm-actions": 0.80, "kernel-cpd-told": 0.85})},
        "metaworld-b": {"codes": 3, "peers": peer_rows({"hmm-actions": 0.60, "kernel-cpd-told": 0.70})},
        "shuttle": {"codes": 2, "peers": peer_rows({"hmm-actions": 1.0})}}}
    text = peers.merged_table(ours, theirs)
    lines = text.splitlines()
    assert lines[0] == ("| task | K | digail | hmm-actions | kernel-cpd-told * | best peer | digail - best peer |")
    assert "| metaworld-a | 4 | 0.700 | 0.800 | 0.850 | kernel-cpd-told | -0.150 |" in lines
    assert "| metaworld-b | 3 | 0.900 | 0.600 | 0.700 | kernel-cpd-told | +0.200 |" in lines
    assert "| shuttle | 2 | - | 1.000 | - | hmm-actions | - |" in lines  # digail has no row for it yet
    assert "| median, 2 Meta-World tasks | | 0.800 | 0.700 | 0.775 | kernel-cpd-told | +0.025 |" in lines
    assert "over the 2 Meta-World tasks: +0.025" in text
    assert "told the true number of segments of every episode" in text


def test_rows_already_in_the_json_are_skipped(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    out = tmp_path / "peers.json"
    row = {"seed": 0, "accuracy": 0.5, "command": "earlier"}
    out.write_text(json.dumps({"tasks": {"toy": {"codes": 2, "demos": "d", "description": "toy",
                                                 "peers": {"hmm-actions": {"seeds": [row]}}}},
                               "commands": ["earlier"]}))
    bench = SimpleNamespace(task_data=lambda name, data: ("d", 2, True, "toy"), task_names=lambda: ["toy"])
    monkeypatch.setattr(peers, "benchmark_module", lambda: bench)

    def fail(*_args, **_kwargs):
        raise AssertionError("a row already measured was measured again")

    monkeypatch.setattr(peers, "run_peer", fail)
    peers.main(["--tasks", "toy", "--peers", "hmm-actions", "--seeds", "0", "--out", str(out)])
    assert json.loads(out.read_text())["tasks"]["toy"]["peers"]["hmm-actions"]["seeds"] == [row]


def test_table_mode_writes_the_figure(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    pytest.importorskip("matplotlib")
    theirs = {"tasks": {"metaworld-a": {"codes": 4, "peers": peer_rows({"hmm-actions": 0.8, "kernel-cpd-told": 0.85})}}}
    (tmp_path / "peers.json").write_text(json.dumps(theirs))
    (tmp_path / "ours.json").write_text(json.dumps({"tasks": {"metaworld-a": {"median": {"accuracy": 0.7}}}}))
    figure = tmp_path / "peers.png"
    peers.main(["--table", "--out", str(tmp_path / "peers.json"), "--digail", str(tmp_path / "ours.json"),
                "--figure", str(figure)])
    assert figure.stat().st_size > 1000
    assert "kernel-cpd-told *" in capsys.readouterr().out


def test_table_marks_cells_with_fewer_seeds() -> None:
    theirs = {"tasks": {"metaworld-a": {"codes": 4, "peers": {
        "hmm-actions": {"seeds": [{}, {}, {}], "median": {"accuracy": 0.8}},
        "linreg-hmm": {"seeds": [{}], "median": {"accuracy": 0.6}}}}}}
    assert "| metaworld-a | 4 | - | 0.800 | 0.600 (1 of 3) | hmm-actions | - |" in peers.merged_table({}, theirs)
