"""The few-demonstration Fetch table reads run folders as `benchmarks/fetch_fewdemo.sh` writes them."""

from __future__ import annotations

import json
from pathlib import Path

from conftest import repo_module

fetch_fewdemo = repo_module("benchmarks/fetch_fewdemo.py")
collect, markdown, table = fetch_fewdemo.collect, fetch_fewdemo.markdown, fetch_fewdemo.table


def _run(root: Path, name: str, curve: list[tuple[int, float]], success: float | None) -> None:
    run = root / name
    run.mkdir(parents=True)
    lines = ["step,iteration,eval/success_rate,losses/policy,perf/sps"]
    for step, s in curve:  # training rows have no eval; each trains 4096 steps at 2048 steps/s
        lines += [f"{step},{step // 4096},{s},,", f"{step + 4096},{step // 4096},,0.1,2048"]
    (run / "metrics.csv").write_text("\n".join(lines) + "\n")
    if success is not None:
        (run / "eval.json").write_text(json.dumps({"episodes": 100, "success_rate": success, "grasp_rate": 1.0,
                                                   "lift_rate": 0.5, "dense_return": -6.0, "sparse_return": -20.0}))


def test_medians_over_finished_seeds_and_steps_to_each_level(tmp_path: Path) -> None:
    _run(tmp_path / "d4", "digail-l2_s0", [(0, 0.1), (20480, 0.6), (40960, 0.95)], 0.9)
    _run(tmp_path / "d4", "digail-l2_s1", [(0, 0.0), (20480, 0.2), (40960, 0.4)], 0.3)
    _run(tmp_path / "d4", "digail-l2_s2", [(0, 0.0), (20480, 0.5)], 0.7)
    _run(tmp_path / "d4", "gail-l2_s0", [(0, 0.0), (20480, 0.1)], None)  # still training
    (tmp_path / "d4" / "notes_s0").mkdir()  # not a method: ignored
    records = collect(tmp_path)
    by = {(r["method"], r["seed"]): r for r in records}
    assert len(records) == 4 and by[("gail-l2", 0)]["status"] == "running"
    assert by[("digail-l2", 0)]["steps_to_0.5"] == 20480 and by[("digail-l2", 0)]["steps_to_0.9"] == 40960
    assert by[("digail-l2", 1)]["steps_to_0.5"] is None
    assert by[("digail-l2", 0)]["train_minutes"] == round(45056 / 2048 / 60, 1)  # to its last step at 2048/s
    assert by[("digail-l2", 0)]["command"] == "benchmarks/fetch_fewdemo.sh 4 digail-l2 0"
    (row,) = table(records)
    assert row["median_success_rate"] == 0.7 and row["per_seed_success_rate"] == [0.9, 0.3, 0.7]
    assert row["env_steps"] == 40960
    assert "0.90 / 0.30 / 0.70 (**0.70**)" in markdown([row])


def test_the_ablation_table_gives_steps_to_each_level_and_ds_late_state(tmp_path: Path) -> None:
    ablation_markdown = fetch_fewdemo.ablation_markdown

    _run(tmp_path / "d4", "digail-l2-rel_s0", [(0, 0.1), (20480, 0.6), (40960, 0.7)], 0.7)
    _run(tmp_path / "d4", "digail-l2-rel-shuffle_s0", [(0, 0.0), (20480, 0.1)], 0.1)
    metrics = tmp_path / "d4" / "digail-l2-rel_s0" / "metrics.csv"
    late = [(0.5, 0.9)] * 5 + [(1.0, 0.1)] * 10  # D's (expert accuracy, reward) per iteration: the last 10 count
    text = metrics.read_text().replace("losses/policy", "losses/policy,disc/acc_expert,rollout/disc_reward", 1)
    metrics.write_text(text + "".join(f"{50000 + i},{i},,,{acc},{rew}\n" for i, (acc, rew) in enumerate(late)))
    lines = ablation_markdown(collect(tmp_path)).splitlines()
    assert len(lines) == 4
    assert lines[2].startswith("| Directed-Info GAIL + L2")
    assert "| 1.00 | 20k | not reached | 1.00 | 0.10 | 0 |" in lines[2]
    assert lines[3].startswith("| codes shuffled each step | 0.10 (**0.10**) | 1.00 | not reached | not reached | - |")
