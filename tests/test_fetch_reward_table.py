"""The full-budget reward table: evaluated run folders first, recorded results for the rows measured elsewhere,
medians over seeds, and the late D scalars that say whether the reward still taught."""

from __future__ import annotations

import json
from pathlib import Path

from conftest import repo_module

repo_module("benchmarks/fetch_fewdemo.py")  # the table reads run folders with its record()
full = repo_module("benchmarks/fetch_reward_table.py")


def _run(root: Path, name: str, success: float | None, acc: float) -> None:
    run = root / "d4" / name
    run.mkdir(parents=True)
    lines = ["step,iteration,eval/success_rate,disc/acc_expert,rollout/disc_reward,perf/sps"]
    lines += [f"{4096 * i},{i},{0.1 * (i % 5 == 0)},{acc},0.02,1000" for i in range(1, 31)]
    (run / "metrics.csv").write_text("\n".join(lines) + "\n")
    (run / "config.json").write_text(json.dumps({"train": {"iterations": 30}}))
    if success is not None:
        (run / "eval.json").write_text(json.dumps({"episodes": 100, "success_rate": success, "grasp_rate": 0.9,
                                                   "lift_rate": 0.8, "dense_return": -9.0, "sparse_return": -40.0}))


def test_rows_take_run_folders_first_and_recorded_results_for_the_rest(tmp_path: Path) -> None:
    for seed, success in enumerate((0.5, 0.1, 0.3)):
        _run(tmp_path, f"digail-l2-rel-argmax-noise-1m_s{seed}", success, 0.9)
    _run(tmp_path, "flatbc-l2-rel-noise-1m_s0", None, 1.0)  # still training: not in the table
    kept = [{"demos": 4, "method": "digail-l2-rel-argmax-1m", "seed": s, "status": "done", "success_rate": v,
             "grasp_rate": 0.95, "lift_rate": 0.9, "late_disc_acc_expert": 1.0, "late_disc_reward": 0.007,
             "env_steps": 999424.0, "curve": []} for s, v in enumerate((0.09, 0.34, 0.55))]
    kept.append({**kept[0], "demos": 1})  # another demonstration count: ignored
    records = full.collect(tmp_path, kept)
    assert [(r["method"], r["seed"]) for r in records] == [
        ("digail-l2-rel-argmax-1m", 0), ("digail-l2-rel-argmax-1m", 1), ("digail-l2-rel-argmax-1m", 2),
        ("digail-l2-rel-argmax-noise-1m", 0), ("digail-l2-rel-argmax-noise-1m", 1),
        ("digail-l2-rel-argmax-noise-1m", 2)]
    rows = {r["method"]: r for r in full.table(records)}
    noise = rows["digail-l2-rel-argmax-noise-1m"]
    assert noise["median_success_rate"] == 0.3 and noise["per_seed_success_rate"] == [0.5, 0.1, 0.3]
    assert noise["median_late_disc_acc_expert"] == 0.9
    assert "flatbc-l2-rel-noise-1m" not in rows
    text = full.markdown(full.table(records))
    assert "| Directed-Info GAIL + L2, D by cross-entropy (today's) | 0.09 / 0.34 / 0.55 (**0.34**) | 0.95 | 0.90 " \
           "| 1.00 | 0.007 | 999k |" in text
    assert "| Directed-Info GAIL + L2, D's inputs noised (sigma 0.15) | 0.50 / 0.10 / 0.30 (**0.30**) |" in text
    # 1 demonstration: its own rows (today's 410k runs), its own records
    one = full.collect(tmp_path, [{**kept[0], "demos": 1, "method": "flatbc-l2-rel"}], demos=1)
    assert [(r["method"], r["demos"]) for r in one] == [("flatbc-l2-rel", 1)]
    assert full.table(one, demos=1)[0]["label"].startswith("GAIL + L2 from flat BC, D by cross-entropy (today's")


def test_the_figure_follows_the_median_seed(tmp_path: Path) -> None:
    for seed, success in enumerate((0.5, 0.1, 0.3)):
        _run(tmp_path, f"digail-l2-rel-argmax-noise-1m_s{seed}", success, 0.9)
    records = full.collect(tmp_path, [])
    run = full.median_seed_run(tmp_path, records, "digail-l2-rel-argmax-noise-1m")
    assert run == tmp_path / "d4" / "digail-l2-rel-argmax-noise-1m_s2"
    curve = full.disc_curve(run)
    assert curve[0] == (4096.0, 0.9, 0.02) and len(curve) == 6  # every fifth of 30 iterations
    full.figure(records, tmp_path / "fig.png", tmp_path)
    assert (tmp_path / "fig.png").stat().st_size > 10_000
