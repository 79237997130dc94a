"""The imitation-reward screen's table reads run folders as `benchmarks/fetch_fewdemo.sh` writes them."""

from __future__ import annotations

import json
from pathlib import Path

from conftest import repo_module

repo_module("benchmarks/fetch_fewdemo.py")  # fetch_rewards reads the run folders with its helpers
fetch_rewards = repo_module("benchmarks/fetch_rewards.py")


def _run(root: Path, name: str, acc: list[float] | None, rewards: list[float], success: float | None) -> None:
    run = root / name
    run.mkdir(parents=True)
    lines = ["step,iteration,eval/success_rate,disc/acc_expert,rollout/disc_reward,perf/sps", "0,0,0.05,,,"]
    for i, r in enumerate(rewards):
        a = "" if acc is None else acc[i]
        lines.append(f"{4096 * (i + 1)},{i + 1},{0.25 if i == 3 else ''},{a},{r},2048")
    (run / "metrics.csv").write_text("\n".join(lines) + "\n")
    (run / "config.json").write_text(json.dumps({"train": {"iterations": len(rewards)}}))
    if success is not None:
        (run / "eval.json").write_text(json.dumps({"episodes": 100, "success_rate": success, "grasp_rate": 0.9,
                                                   "lift_rate": 0.8, "dense_return": -9.0}))


def test_screen_rows_say_whether_the_reward_still_teaches(tmp_path: Path) -> None:
    ones = [0.5, 0.6, 0.7, 0.8, 0.9, 1.0, 1.0, 1.0, 1.0, 1.0]
    _run(tmp_path / "d4", "digail-l2-rel-argmax_s0", ones, [0.3] * 5 + [0.01] * 5, 0.12)
    _run(tmp_path / "d4", "digail-l2-rel-argmax-ots_s0", None, [-1.2] * 5 + [-0.8] * 5, None)
    _run(tmp_path / "d4", "digail-l2-rel-argmax-sac_s0", ones, [0.1] * 10, 0.0)  # not a screened reward: left out
    records = fetch_rewards.collect(tmp_path, 4, 0)
    by = {r["method"]: r for r in records}
    assert set(by) == {"digail-l2-rel-argmax", "digail-l2-rel-argmax-ots"}
    base, ots = by["digail-l2-rel-argmax"], by["digail-l2-rel-argmax-ots"]
    assert base["disc_acc_expert_first5"] == 0.7 and base["disc_acc_expert_last5"] == 1.0
    assert base["reward_per_step_first5"] == 0.3 and base["reward_per_step_last5"] == 0.01
    assert base["periodic_success_max"] == 0.25 and base["success_rate"] == 0.12
    assert base["command"] == "benchmarks/fetch_fewdemo.sh 4 digail-l2-rel-argmax 0 10"
    assert ots["status"] == "running" and ots["disc_acc_expert_last5"] is None
    table = fetch_rewards.markdown(records)
    assert "| today's best: D by binary cross-entropy (GAIL's) | 0.12 | 0.90 | 0.80 | 0.25 | 0.70 / 1.00 |" in table
    assert "| sub-task-aware optimal transport (no D) | running |" in table and "| no D | -1.200 / -0.800 |" in table
