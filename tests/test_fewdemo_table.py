"""The few-demonstration table compares runs stopped at different env steps over one common window of steps."""

from __future__ import annotations

import json
import sys
from pathlib import Path

import pytest
from conftest import repo_module

fewdemo = repo_module("benchmarks/fewdemo.py")
first_reach, table, window_mean = fewdemo.first_reach, fewdemo.table, fewdemo.window_mean


def test_window_mean_averages_only_the_evaluations_inside_the_window() -> None:
    curve = [(0.0, 0.1), (100_000.0, 0.8), (150_000.0, 0.9), (200_000.0, 1.0), (300_000.0, 0.2)]
    assert window_mean(curve, (100_000.0, 200_000.0)) == pytest.approx(0.9)
    assert first_reach(curve, 0.9) == 150_000.0 and first_reach(curve, 1.01) is None


def test_a_run_stopped_before_the_window_ends_has_no_window_mean() -> None:
    """A run stopped at 117k has no figure for 100k-200k: its early evaluations alone would flatter or sink it."""
    assert window_mean([(100_000.0, 0.9), (110_000.0, 1.0)], (100_000.0, 200_000.0)) is None


def test_the_table_takes_medians_over_seeds_of_both_figures() -> None:
    def run(seed: int, final: float, window: float | None) -> dict[str, object]:
        return {"env": "Hopper-v5", "demos_episodes": 4, "demos_subsample": 20, "method": "gail", "learner": "sac",
                "seed": seed, "normalized_return": final, "window_mean": window, "partial": True}

    (row,) = table([run(0, 0.5, None), run(1, 0.9, 0.7), run(2, 1.0, 0.8)])
    assert row["median_normalized_return"] == pytest.approx(0.9)
    assert row["median_window_mean"] == pytest.approx(0.75) and row["window_seeds"] == [1, 2]


def test_the_markdown_table_puts_each_seed_in_its_place() -> None:
    markdown = fewdemo.markdown

    def run(seed: int, final: float | None, learner: str | None) -> dict[str, object]:
        return {"env": "Hopper-v5", "demos_episodes": 4, "demos_subsample": 20, "method": "gail" if learner else
                "bc (vae)", "learner": learner, "seed": seed, "normalized_return": final, "window_mean": None,
                "env_steps": 200_000.0 if learner else 0.0, "steps_to_0.9": 50_000.0, "steps_to_0.95": None,
                "wall_time_s": 600.0, "from_curve": False}

    text = markdown([run(2, 0.9, "sac"), run(0, 0.5, "sac"), run(1, 0.1, None)])
    rows = [line for line in text.splitlines() if line.startswith("| Hopper")]
    assert rows[0].startswith("| Hopper-v5 | 4, every 20th | BC (the VAE's policy) | 1 | 0 | 0.100 |")
    assert "| GAIL + SAC | 0 / 2 | 200k / 200k | 0.500 / 0.900, **0.700** |" in rows[1]
    assert "50k / -, 50k / -" in rows[1] and rows[1].endswith("| 10 min |")


def test_merge_drops_the_entries_a_longer_run_continues(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """A 1M run continues a 430k one: the 430k entry must leave the table, not share its median."""
    main = fewdemo.main

    def entry(run: str) -> dict[str, object]:
        return {"run": run, "env": "Walker2d-v5", "demos_episodes": 4, "demos_subsample": 20, "method": "gail",
                "learner": "sac", "seed": 0, "normalized_return": 0.5, "curve": [[1000.0, 0.5]], "partial": False}

    out = tmp_path / "fewdemo.json"
    out.write_text(json.dumps({"runs": [entry("old"), entry("kept")]}))
    monkeypatch.setattr(sys, "argv", ["fewdemo.py", "--merge", "--drop", "old", "--out", str(out)])
    main()
    assert [r["run"] for r in json.loads(out.read_text())["runs"]] == ["kept"]
    monkeypatch.setattr(sys, "argv", ["fewdemo.py", "--merge", "--drop", "missing", "--out", str(out)])
    with pytest.raises(SystemExit):
        main()


def test_merge_puts_a_rerun_in_its_place_and_leaves_the_other_entries_alone(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """A rerun replaces its entry where it stood; kept entries keep their stored window means, made from full curves."""

    def entry(run: str, final: float) -> dict[str, object]:
        return {"run": run, "env": "Walker2d-v5", "demos_episodes": 1, "demos_subsample": 1, "method": "gail",
                "learner": "sac", "seed": 0, "normalized_return": final, "curve": [[150000.0, 0.5]],
                "partial": False, "window": list(fewdemo.WINDOW), "window_mean": 0.123456789}

    out = tmp_path / "fewdemo.json"
    out.write_text(json.dumps({"runs": [entry("a", 0.1), entry("b", 0.2), entry("c", 0.3)]}))
    monkeypatch.setattr(fewdemo, "summarise_run", lambda path, window: entry(str(path), 0.9))
    monkeypatch.setattr(sys, "argv", ["fewdemo.py", "b", "--merge", "--out", str(out)])
    fewdemo.main()
    runs = json.loads(out.read_text())["runs"]
    assert [(r["run"], r["normalized_return"]) for r in runs] == [("a", 0.1), ("b", 0.9), ("c", 0.3)]
    assert runs[0]["window_mean"] == 0.123456789


def test_the_summary_takes_the_start_with_most_seeds_and_shows_where_runs_stopped() -> None:
    summary = fewdemo.summary

    def run(seed: int, final: float, init: str | None, steps: float) -> dict[str, object]:
        return {"env": "Hopper-v5", "demos_episodes": 4, "demos_subsample": 20, "method": "digail", "learner": "sac",
                "policy_init": init, "seed": seed, "normalized_return": final, "env_steps": steps}

    bc = {"env": "Hopper-v5", "demos_episodes": 4, "demos_subsample": 20, "method": "bc (vae)", "learner": None,
          "seed": 0, "normalized_return": 0.1, "env_steps": 0.0}
    records = [bc, run(0, 0.2, "vae", 1e5), run(0, 0.9, None, 2e5), run(1, 1.0, None, 2.2e5), run(2, 0.7, None, 1e6)]
    (row,) = [line for line in summary(records).splitlines() if line.startswith("| Hopper")]
    assert row == "| Hopper-v5 | 4, every 20th | 0.100 |  |  |  | 0.900 |"
    records[-1]["env_steps"] = 2.1e5
    assert "| 0.900 by 220k |" in summary(records)


def test_the_summary_table_is_the_stored_results_summary() -> None:
    """The results page's few-demonstration summary table is `fewdemo.py --summary` of
    benchmarks/results/few-demos/fewdemo.json."""
    summary = fewdemo.summary

    root = Path(__file__).resolve().parents[1]
    runs = json.loads((root / "benchmarks/results/few-demos/fewdemo.json").read_text())["runs"]
    assert summary(runs) in (root / "docs" / "results.md").read_text()
