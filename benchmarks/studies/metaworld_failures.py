"""Where the committed Meta-World runs fail: the last step's info of every failed evaluation episode.

    MUJOCO_GL=egl python benchmarks/studies/metaworld_failures.py --episodes 100 \
        --out benchmarks/studies/results/metaworld_failures.json

For each committed Directed-Info GAIL + L2 run folder (benchmarks/results/runs/metaworld_<task>_digail-l2_s<seed>),
the evaluation episodes (deterministic, closed-loop q, seeds 10000 on, as `digail evaluate`) that end without
success are read at their last step: Meta-World's `grasp_success` (holding the object), `near_object` (the hand at
it) and `obj_to_target` (metres from the object to the goal), so a failure is placed in the task's stages.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np

from digail.checkpoint import load_model
from digail.eval.returns import run_episodes

RUNS = Path(__file__).resolve().parents[1] / "results" / "runs"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--episodes", type=int, default=100)
    parser.add_argument("--out", type=Path)
    args = parser.parse_args()
    result = {}
    for run in sorted(RUNS.glob("metaworld_*_digail-l2_s*")):
        model, meta = load_model(run / "model.pt")
        episodes = run_episodes(model, meta["env_id"], args.episodes, 10000, deterministic=True)
        failed = [e.final_info for e in episodes if not e.final_info.get("success")]
        row = {"env_id": meta["env_id"], "episodes": len(episodes), "failed": len(failed)}
        if failed:
            row.update(
                failed_holding=float(np.mean([bool(f.get("grasp_success")) for f in failed])),
                failed_hand_at_object=float(np.mean([bool(f.get("near_object")) for f in failed])),
                failed_obj_to_target_median=float(np.median([f.get("obj_to_target", np.nan) for f in failed])))
        result[run.name] = row
        print(run.name, row, flush=True)
    if args.out:
        args.out.parent.mkdir(parents=True, exist_ok=True)
        args.out.write_text(json.dumps(result, indent=1) + "\n")


if __name__ == "__main__":
    main()
