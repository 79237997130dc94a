"""Where few-demonstration Fetch agents fail: the stage each failed evaluation episode reached, and how it ended.

    MUJOCO_GL=egl python benchmarks/studies/fetch_failures.py --episodes 100 \
        --run runs/fetchfew/d4/digail-l2-rel-argmax-noise-1m_s{0,1,2} runs/fetchfew/d4/flatbc-l2-rel-noise-1m_s{0,1,2} \
        --out benchmarks/studies/results/fetch_failures.json

Each run's evaluation episodes (deterministic, closed-loop q, seeds 10000 on, as `digail evaluate`) are read step
by step: the furthest oracle stage of the task (`info["subtask"]`: 0 reach, 1 grasp, 2 carry, 3 place, the object
within 2 cm of the goal at some step), whether the object was ever lifted, whether it is held at the end, and how
far from the goal it ends. Goals are split into those in the air and those on the table (the goal more than 1 cm
above the resting object), since only the former need the object carried up. A failure that reached the place
stage and then left it lost the object at the goal; one still holding the object off the goal never got there.
"""

from __future__ import annotations

import argparse
import json
import os
from pathlib import Path
from typing import Any

import numpy as np

os.environ.setdefault("MUJOCO_GL", "egl")

STAGES = ("reach", "grasp", "carry", "place")
"""the oracle stages of `digail.envs.fetch` (info["subtask"])"""


def classify(episode: Any) -> dict[str, Any]:
    """One episode's stage reached, its ending and its goal (in the air or on the table)."""
    stages = [int(i.get("subtask", 0)) for i in episode.infos]
    obs0 = np.asarray(episode.obs[0])
    return {"success": bool(episode.final_info.get("is_success")),
            "stage": max(stages),
            "lifted": bool(np.any(np.asarray(episode.info_values.get("lifted", [])) > 0)),
            "holding_at_end": bool(episode.info_values["grasped"][-1] > 0),
            "final_distance_m": float(-episode.info_values["dense_reward"][-1]),
            "goal_in_air": bool(obs0[27] - obs0[5] > 0.01)}


def summary(rows: list[dict[str, Any]]) -> dict[str, Any]:
    """Success by goal height and the failures by the stage they reached and how they ended."""
    air = [r for r in rows if r["goal_in_air"]]
    table = [r for r in rows if not r["goal_in_air"]]
    failed = [r for r in rows if not r["success"]]
    out: dict[str, Any] = {
        "episodes": len(rows), "success": float(np.mean([r["success"] for r in rows])),
        "goals_in_air": len(air),
        "success_goal_in_air": round(float(np.mean([r["success"] for r in air])), 3) if air else None,
        "success_goal_on_table": round(float(np.mean([r["success"] for r in table])), 3) if table else None,
        "failed": len(failed),
        "failed_goal_in_air": sum(r["goal_in_air"] for r in failed)}
    for k, name in enumerate(STAGES):
        out[f"failed_furthest_{name}"] = sum(r["stage"] == k for r in failed)
    out["failed_lifted"] = sum(r["lifted"] for r in failed)
    out["failed_holding_at_end"] = sum(r["holding_at_end"] for r in failed)
    out["failed_reached_place_then_left"] = sum(r["stage"] == 3 for r in failed)
    if failed:
        out["failed_final_distance_median_m"] = round(float(np.median([r["final_distance_m"] for r in failed])), 4)
        holding = [r["final_distance_m"] for r in failed if r["holding_at_end"]]
        if holding:
            out["failed_holding_final_distance_median_m"] = round(float(np.median(holding)), 4)
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--run", type=Path, nargs="+", required=True, help="trained Fetch run folders")
    parser.add_argument("--episodes", type=int, default=100)
    parser.add_argument("--out", type=Path)
    args = parser.parse_args()
    import torch

    from digail.checkpoint import load_model
    from digail.eval.returns import run_episodes

    torch.set_num_threads(1)
    out: dict[str, Any] = {"episodes": args.episodes, "seeds": "10000 on, deterministic"}
    for run in args.run:
        model, meta = load_model(run / "model.pt")
        played = run_episodes(model, meta["env_id"], args.episodes, 10000, deterministic=True, keep_obs=args.episodes)
        out[str(run)] = summary([classify(e) for e in played])
        print(run, out[str(run)], flush=True)
    if args.out:
        args.out.parent.mkdir(parents=True, exist_ok=True)
        args.out.write_text(json.dumps(out, indent=1) + "\n")
        print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
