"""The run folders committed under benchmarks/results/runs load, act and score near what their eval.json claims."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from digail.checkpoint import load_model
from digail.eval.returns import evaluate

RUNS = Path(__file__).resolve().parents[1] / "benchmarks" / "results" / "runs"


@pytest.mark.mujoco
@pytest.mark.parametrize("run", sorted(p.name for p in RUNS.iterdir() if (p / "model.pt").exists()))
def test_committed_run_reevaluates_near_its_claim(run: str) -> None:
    folder = RUNS / run
    claim = json.loads((folder / "eval.json").read_text())
    model, meta = load_model(folder / "model.pt")
    # the first episodes of the claimed evaluation (same seeds), a few only: the claim is their 300-episode mean
    result = evaluate(model, meta["env_id"], episodes=3, seed=claim["seed"], with_expert=False)
    spread = max(3 * claim["std_return"], 0.05 * abs(claim["mean_return"]))
    assert abs(result["mean_return"] - claim["mean_return"]) <= spread, (result["mean_return"], claim["mean_return"])
