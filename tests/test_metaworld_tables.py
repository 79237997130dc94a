"""The Meta-World few-demonstration tables and rows as the benchmark writes and the results page prints them."""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import pytest
from conftest import repo_module

tables = repo_module("benchmarks/metaworld_tables.py")
fewdemo = repo_module("benchmarks/metaworld_fewdemo.py")


def _row(task: str, method: str, seed: int, success: float, iterations: int | None = None) -> dict:
    return {"task": task, "method": method, "seed": seed, "success_rate": success, "mean_length": 90.0,
            "iterations": iterations}


def test_tables_give_the_seeds_median_and_mark_a_lead_of_two_tenths(tmp_path: Path,
                                                                      monkeypatch: pytest.MonkeyPatch) -> None:
    rows = [_row("hammer", "bc", s, v) for s, v in enumerate((1.0, 0.98, 1.0))]
    rows += [_row("hammer", "flatbc", s, v) for s, v in enumerate((0.97, 0.5, 0.96))]
    rows += [_row("box-close", "bc", s, v) for s, v in enumerate((0.6, 0.65, 0.8))]
    rows += [_row("box-close", "flatbc", s, v) for s, v in enumerate((0.19, 0.48, 0.54))]
    rows += [_row("box-close", "digail-l2", s, v, 61) for s, v in enumerate((0.7, 0.72, 0.9))]
    rows += [_row("box-close", "flatbc-l2", s, v, 61) for s, v in enumerate((0.3, 0.64, 0.4))]
    rows += [_row("box-close", "digail-l2-noise", 0, 0.5, 61)]
    rows += [_row("hammer", "digail-l2", s, v, 30) for s, v in enumerate((1.0, 1.0, 0.99))]
    (tmp_path / "metaworld_fewdemo.json").write_text(json.dumps({"rows": rows}))
    monkeypatch.setattr(tables, "RESULTS", tmp_path)
    text = tables.fewdemo()
    # tasks in the how-to's order; the BC table's lead is BC's median less flat BC's
    assert text.index("| box-close | 4 |") < text.index("| hammer | 4 |")
    assert "| box-close | 4 | 0.65 (0.60 / 0.65 / 0.80) | 0.48 (0.19 / 0.48 / 0.54) | +0.17 |" in text
    assert "| hammer | 4 | 1.00 (1.00 / 0.98 / 1.00) | 0.96 (0.97 / 0.50 / 0.96) | +0.04 |" in text
    # one table per training length, each holding only the tasks trained that long
    thirty, sixty_one = text.split("30 PPO iterations (122,880 env steps):")[1].split("61 PPO iterations")
    assert "| hammer | 1.00 (1.00 / 1.00 / 0.99) | - | - | - |" in thirty and "box-close" not in thirty
    assert "| box-close | 0.72 (0.70 / 0.72 / 0.90) | 0.40 (0.30 / 0.64 / 0.40) | 0.50 (one seed) | **+0.32** |" \
        in sixty_one


def test_rows_carry_the_budget_and_what_d_paid_per_iteration(tmp_path: Path) -> None:
    run = tmp_path / "hammer" / "digail-l2_s1"
    run.mkdir(parents=True)
    (run / "eval.json").write_text(json.dumps({"episodes": 100, "success_rate": 0.97, "mean_length": 70.0}))
    (run / "metrics.csv").write_text("step,iteration,disc/acc_expert,rollout/disc_reward,perf/sps\n"
                                     "4096,1,0.5,-0.77,2100\n8192,2,,-0.9,2000\n")
    (run / "config.json").write_text(json.dumps({"train": {"iterations": 2}}))
    (tmp_path / "hammer" / "bc_s1").mkdir()
    (tmp_path / "hammer" / "bc_s1" / "model.pt").write_bytes(b"")  # the start it was trained from
    args = argparse.Namespace(runs=tmp_path, demos=10, episodes=100, iterations=2)
    row = fewdemo.one("hammer", "digail-l2", 1, args)  # trained as long as asked and evaluated: not run again
    assert row["commands"] == ["(done earlier)"] and row["iterations"] == 2 and row["env_steps"] == 8192
    assert row["success_rate"] == 0.97
    assert row["per_iteration"] == {"disc_acc_expert": [0.5, None], "disc_reward": [-0.77, -0.9],
                                    "sps": [2100.0, 2000.0]}


def test_a_lead_of_exactly_two_tenths_counts_despite_float_rounding() -> None:
    assert 0.86 - 0.66 < 0.2  # what binary floats make of it
    assert tables._lead(0.86, 0.66) == "**+0.20**" and tables._lead(0.85, 0.66) == "+0.19"


downstream = repo_module("benchmarks/metaworld_codes_downstream.py")


def test_codes_downstream_sets_the_new_start_beside_the_old(tmp_path: Path) -> None:
    def seg(accuracy: float) -> dict:
        return {"segmentation": {"accuracy": accuracy, "boundary_f1_5": 0.5, "reading": "offline", "episodes": 50}}

    old = [_row("box-close", "bc", s, v) for s, v in enumerate((0.6, 0.65, 0.8))]
    old += [_row("box-close", "digail-l2", s, v, 61) for s, v in enumerate((0.83, 0.7, 0.85))]
    old += [_row("box-close", "digail-l2", s, 0.1, 30) for s in range(3)]  # another length: not this table's
    again = [{**_row("box-close", "bc", s, v), **seg(a)} for s, (v, a) in enumerate(((0.6, 0.7), (0.65, 0.74),
                                                                                      (0.8, 0.72)))]
    new = [{**_row("box-close", "bc", s, v), **seg(a)} for s, (v, a) in enumerate(((0.9, 0.99), (0.7, 0.9),
                                                                                    (0.8, 0.98)))]
    new += [_row("box-close", "digail-l2", s, v, 61) for s, v in enumerate((0.9, 0.95))]  # seed 2 still training
    for name, rows in (("metaworld_fewdemo.json", old), ("metaworld_fewdemo_oldstart_bc.json", again),
                       ("metaworld_fewdemo_newstart.json", new)):
        (tmp_path / name).write_text(json.dumps({"rows": rows}))
    data = downstream.collect(tmp_path)
    box = data["box-close"]
    assert box["accuracy_old"]["median"] == 0.72 and box["accuracy_new"]["median"] == 0.98
    assert box["old_bc_differs"] == {}
    text = downstream.table(data)
    assert ("| box-close | 0.72 (0.70 / 0.74 / 0.72) | 0.98 (0.99 / 0.90 / 0.98) | 0.65 (0.60 / 0.65 / 0.80) | "
            "0.80 (0.90 / 0.70 / 0.80) | +0.15 | 0.83 (0.83 / 0.70 / 0.85) | 0.93 (0.90 / 0.95) | +0.16 (seeds 0, 1) |"
            ) in text  # the change over the seeds both have: 0.925 - 0.765
    assert "| hammer | - | - | - | - | - |" in text  # a task not measured says so
    # the old start's BC made again with other numbers is told, not hidden
    again[0]["success_rate"] = 0.5
    (tmp_path / "metaworld_fewdemo_oldstart_bc.json").write_text(json.dumps({"rows": again}))
    assert downstream.collect(tmp_path)["box-close"]["old_bc_differs"] == {"0": [0.6, 0.5]}
