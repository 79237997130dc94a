"""The imitation-reward screen's table reads run folders as `benchmarks/fetch_fewdemo.sh` writes them."""

from __future__ import annotations

import json
from pathlib import Path

from conftest import repo_module

repo_module("benchmarks/fetch_fewdemo.py")  # fetch_rewards reads the run folders with its helpers
fetch_rewards = repo_module("benchmarks/studies/fetch_rewards.py")


def _run(root: Path, name: str, acc: list[float] | None, rewards: list[float], success: float | None) -> None:
    run = root / name
    run.mkdir(parents=True)
    lines = ["step,iteration,eval/success_rate,disc/acc_expert,rollout/disc_reward,perf/sps", "0,0,0.05,,,"]
    for i, r in enumerate(rewards):
        a = "" if acc is None else acc[i]
        lines.append(f"{4096 * (i + 1)},{i + 1},{0.25 if i == 3 else ''},{a},{r},2048")
    (run / "metrics.csv").write_text("\n".join(lines) + "\n")
    (run / "config.json").write_text(json.dumps({"train": {"iterations": len(rewards)}}))
    if len(rewards) == 50:  # a run continued from 30 iterations keeps that evaluation
        (run / "eval.iteration-30.json").write_text(json.dumps({"episodes": 100, "success_rate": 0.04,
                                                                "grasp_rate": 0.7, "lift_rate": 0.6,
                                                                "dense_return": -12.0}))
    if success is not None:
        (run / "eval.json").write_text(json.dumps({"episodes": 100, "success_rate": success, "grasp_rate": 0.9,
                                                   "lift_rate": 0.8, "dense_return": -9.0}))


def test_screen_rows_say_whether_the_reward_still_teaches(tmp_path: Path) -> None:
    acc = [0.5, 0.6, 0.7, 0.8, 0.9] + [1.0] * 45
    _run(tmp_path / "d4", "digail-l2-rel-argmax_s0", acc, [0.3] * 5 + [0.02] * 20 + [0.01] * 25, 0.12)
    _run(tmp_path / "d4", "digail-l2-rel-argmax-ots_s0", None, [-1.2] * 25 + [-0.8] * 5, 0.06)
    _run(tmp_path / "d4", "digail-l2-rel-argmax-pu_s0", acc[:12], [0.2] * 12, None)  # still training
    _run(tmp_path / "d4", "digail-l2-rel-argmax-sac_s0", acc, [0.1] * 50, 0.0)  # not a screened reward: left out
    records = fetch_rewards.collect(tmp_path, 4, 0)
    by = {r["method"]: r for r in records}
    assert set(by) == {"digail-l2-rel-argmax", "digail-l2-rel-argmax-ots", "digail-l2-rel-argmax-pu"}
    base, ots, pu = by["digail-l2-rel-argmax"], by["digail-l2-rel-argmax-ots"], by["digail-l2-rel-argmax-pu"]
    assert base["disc_acc_expert_it1_5"] == 0.7 and base["disc_acc_expert_it26_30"] == 1.0
    assert base["reward_per_step_it1_5"] == 0.3 and base["reward_per_step_it26_30"] == 0.01
    assert base["eval_30"]["success_rate"] == 0.04 and base["eval_50"]["success_rate"] == 0.12
    assert base["periodic_success_max"] == 0.25
    assert base["command"] == "benchmarks/fetch_fewdemo.sh 4 digail-l2-rel-argmax 0 50"
    assert ots["eval_30"]["success_rate"] == 0.06 and ots["eval_50"] is None and ots["disc_acc_expert_it1_5"] is None
    assert pu["status"] == "running" and pu["eval_30"] is None
    table = fetch_rewards.markdown(records)
    base_row = "| today's best: D by binary cross-entropy (GAIL's) | 0.04 / 0.12 | 0.70 / 0.90 | 0.25 | 0.70 / 1.00 |"
    assert base_row in table
    assert "| sub-task-aware optimal transport (no D) | 0.06 / - |" in table and "| no D | -1.200 / -0.800 |" in table
    assert "| D positive-unlabeled (prior 0.5) | - / running |" in table
    # a row whose run folder is elsewhere keeps its recorded record; one found here replaces its record
    kept = [{**base, "method": "digail-l2-rel-argmax-noise", "label": "old"}, {**pu, "status": "old"}]
    again = {r["method"]: r for r in fetch_rewards.collect(tmp_path, 4, 0, kept)}
    assert again["digail-l2-rel-argmax-noise"]["eval_50"]["success_rate"] == 0.12
    assert again["digail-l2-rel-argmax-noise"]["label"] == "D's inputs noised (sigma 0.15)"
    assert again["digail-l2-rel-argmax-pu"]["status"] == "running"
    # a longer run of a screened method (the first 100 iterations of a 1M run) is not the screen's: the record stays
    _run(tmp_path / "d4", "digail-l2-rel-argmax-noise_s0", acc * 2, [0.2] * 100, 0.3)
    again = {r["method"]: r for r in fetch_rewards.collect(tmp_path, 4, 0, kept)}
    assert again["digail-l2-rel-argmax-noise"]["eval_50"]["success_rate"] == 0.12
    # a run on the relative-observation env sits beside the root, in <root>-rel
    _run(tmp_path.with_name(tmp_path.name + "-rel") / "d4", "digail-l2-argmax_s0", acc, [0.3] * 50, 0.2)
    rel = {r["method"]: r for r in fetch_rewards.collect(tmp_path, 4, 0)}["relative:digail-l2-argmax"]
    assert rel["eval_50"]["success_rate"] == 0.2
    assert rel["command"] == "FETCH_OBS=relative benchmarks/fetch_fewdemo.sh 4 digail-l2-argmax 0 50"
    assert list(again)[:3] == ["digail-l2-rel-argmax", "digail-l2-rel-argmax-pu", "digail-l2-rel-argmax-noise"]
