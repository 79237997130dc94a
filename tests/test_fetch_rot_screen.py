"""The off-policy screen's table reads run folders as `benchmarks/fetch_fewdemo.sh` writes them: every
evaluation a continued run kept, one row per evaluation, and the training columns once."""

from __future__ import annotations

import json
from pathlib import Path

from conftest import repo_module

repo_module("benchmarks/fetch_fewdemo.py")  # the table's header helper
rot = repo_module("benchmarks/studies/fetch_rot_screen.py")


def _run(folder: Path, iterations: int, evals: dict[int, float], ot: list[float], kept: list[float]) -> None:
    folder.mkdir(parents=True)
    lines = ["iteration,eval/success_rate,reward/ot_episode,losses/bc_kept", "0,0.0,,"]
    lines += [f"{i + 1},{0.15 if i == 5 else ''},{r},{k}" for i, (r, k) in enumerate(zip(ot, kept, strict=True))]
    (folder / "metrics.csv").write_text("\n".join(lines) + "\n")
    (folder / "config.json").write_text(json.dumps({"train": {"iterations": iterations}}))
    for it, success in evals.items():
        name = "eval.json" if it == iterations else f"eval.iteration-{it}.json"
        (folder / name).write_text(json.dumps({"success_rate": success, "grasp_rate": 0.9, "lift_rate": 0.8}))


def test_rows_follow_the_methods_and_a_continued_run_shows_each_evaluation(tmp_path: Path) -> None:
    ot = [-1.0] * 10 + [-0.7] * 10 + [-0.4] * 10
    _run(tmp_path / "d4" / "digail-l2-argmax-otd-qf-sacfast_s0", 30, {15: 0.01, 30: 0.12}, ot, [0.4] * 20 + [0.1] * 10)
    _run(tmp_path / "d1" / "digail-l2-rel-argmax-ot-qf-sacfast_s0", 30, {30: 0.03}, ot, [0.3] * 30)
    _run(tmp_path / "d4" / "flatbc-l2-rel-ot-qf-sacfast_s1", 30, {30: 0.5}, ot, [0.3] * 30)  # another seed
    (tmp_path / "d4" / "digail-l2-rel-argmax-ot-qf-sacfast_s0").mkdir(parents=True)  # started, not evaluated
    rows = rot.collect(tmp_path, 0)
    assert [(r["demos"], r["method"]) for r in rows] == [(1, "digail-l2-rel-argmax-ot-qf-sacfast"),
                                                         (4, "digail-l2-argmax-otd-qf-sacfast")]
    otd = rows[1]
    assert list(otd["evaluations"]) == ["15000", "30000"] and otd["evaluations"]["30000"]["success_rate"] == 0.12
    assert otd["ot_reward_per_step_first10"] == -1.0 and otd["ot_reward_per_step_last10"] == -0.4
    assert otd["bc_kept_first10"] == 0.4 and otd["bc_kept_last10"] == 0.1 and otd["periodic_success_max"] == 0.15
    assert otd["command"] == ("benchmarks/fetch_fewdemo.sh 4 digail-l2-argmax-otd-qf-sacfast 0 15 then "
                              "benchmarks/fetch_fewdemo.sh 4 digail-l2-argmax-otd-qf-sacfast 0 30")
    table = rot.markdown(rows)
    assert "| the first row with 1 demonstration | 1 | 30k | 0.03 | 0.90 | 0.80 | 0.15 | -1.000 / -0.400 |" in table
    assert "| 4 | 15k | 0.01 | 0.90 | 0.80 | (the run continued below) |" in table
