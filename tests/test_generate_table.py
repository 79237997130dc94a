"""The generation benchmark's table keeps what an earlier table measured that this machine has no run of."""

from __future__ import annotations

from typing import Any

import pytest
from conftest import repo_module

generate_bench = repo_module("benchmarks/generate.py")


def _job(seed: int, attempts: int, first_200: float = 0.9) -> dict[str, Any]:
    return {"task": "hammer", "segments": "labels-best", "demos": 3, "seed": seed, "attempts": attempts,
            "rate_first_200": first_200}


def _row(seed: int, size: int, success: float) -> dict[str, Any]:
    return {"task": "hammer", "segments": "labels-best", "demos": 3, "seed": seed, "method": "bc", "size": size,
            "success_rate": success}


def test_sizes_trained_here_join_the_earlier_rows_of_the_same_job() -> None:
    """A job generated again to 500 here keeps the earlier 1000-run's record and its size-1000 row; another seed
    measured only earlier comes along whole, and a row measured in both places is this machine's."""
    earlier = {"jobs": [_job(0, 1700), _job(1, 1700)], "rows": [_row(0, 1000, 1.0), _row(0, 500, 0.5),
                                                               _row(1, 1000, 0.9)]}
    jobs, rows = [_job(0, 800)], [_row(0, 100, 0.7), _row(0, 500, 0.8)]
    generate_bench._keep_earlier(earlier, jobs, rows, None)
    assert [(j["seed"], j["attempts"]) for j in jobs] == [(0, 1700), (1, 1700)]
    assert sorted((r["seed"], r["size"], r["success_rate"]) for r in rows) == [
        (0, 100, 0.7), (0, 500, 0.8), (0, 1000, 1.0), (1, 1000, 0.9)]


def test_a_different_generation_under_the_same_name_is_refused() -> None:
    earlier = {"jobs": [_job(0, 1700, first_200=0.9)], "rows": []}
    with pytest.raises(SystemExit, match="not the same generation"):
        generate_bench._keep_earlier(earlier, [_job(0, 800, first_200=0.5)], [], None)


def test_only_the_tasks_asked_for_are_kept() -> None:
    earlier = {"jobs": [_job(0, 1700)], "rows": [_row(0, 1000, 1.0)]}
    jobs: list[dict[str, Any]] = []
    rows: list[dict[str, Any]] = []
    generate_bench._keep_earlier(earlier, jobs, rows, ["pick-place"])
    assert jobs == [] and rows == []
