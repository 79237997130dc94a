"""Which transport cost grades placing on Fetch? The `ot` reward of a trained agent's episodes, by view and cost.

    MUJOCO_GL=egl python benchmarks/studies/ot_cost_grades.py \
        --run benchmarks/results/runs/fetch4_digail-l2-rel-argmax-ot-qf-sacfast_s0 \
              benchmarks/results/runs/fetch4_digail-l2-argmax-otd-qf-sacfast_s0 \
              benchmarks/results/runs/fetch4_digail-l2-rel-argmax-1m_s1 --episodes 40 \
        --out benchmarks/studies/results/ot_cost_grades.json

The agent's evaluation episodes (deterministic, closed-loop q, seeds 10000 on, as `digail evaluate`) and the
dataset's held-out expert episodes 5-12 are scored whole against the first 4 demonstrations of
digail/fetchpickandplace/expert-v0, as `--train.imitation.reward ot` scores them, for each view of the state
(features standardised on the demonstrations, as D's view is) and each cost. A cost that grades placing gives the
agent's failed episodes a lower reward than its successes and than held-out experts, and ranks the agent's episodes
by how close the block ends to the goal (Spearman's rho of the reward against minus the final distance).
"""

from __future__ import annotations

import argparse
import json
import os
from pathlib import Path

import numpy as np
import torch

os.environ.setdefault("MUJOCO_GL", "egl")

DATASET = "digail/fetchpickandplace/expert-v0"


def spearman(x: np.ndarray, y: np.ndarray) -> float:
    """Spearman's rank correlation (no ties expected: continuous values)."""
    rx, ry = np.argsort(np.argsort(x)), np.argsort(np.argsort(y))
    return float(np.corrcoef(rx, ry)[0, 1])


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--run", type=Path, nargs="+", required=True,
                        help="trained 4-demonstration Fetch run folders")
    parser.add_argument("--episodes", type=int, default=40)
    parser.add_argument("--out", type=Path)
    args = parser.parse_args()
    from digail.commands.train import load_demos

    torch.set_num_threads(1)
    demos, env_id = load_demos(DATASET, episodes=4)
    held_out = load_demos(DATASET, episodes=12)[0][4:12]
    out: dict[str, object] = {"demonstrations": 4, "held_out_episodes": "5-12", "episodes": args.episodes}
    for run in args.run:
        out[str(run)] = grades(run, args.episodes, demos, held_out, env_id)
    if args.out:
        args.out.parent.mkdir(parents=True, exist_ok=True)
        args.out.write_text(json.dumps(out, indent=1) + "\n")
        print(f"wrote {args.out}")


def grades(run: Path, episodes: int, demos: list, held_out: list, env_id: str) -> dict[str, object]:
    """One run's table: per view, cost and time weight, the mean rewards and how they rank the agent's episodes."""
    from digail.algos.rewards.ot import ot_step_rewards, window_mask
    from digail.checkpoint import load_model
    from digail.envs.fetch import distances_view, log_distances_view, placing_view, relative_view
    from digail.eval.returns import run_episodes

    model, _ = load_model(run / "model.pt")
    played = run_episodes(model, env_id, episodes, 10000, deterministic=True, keep_obs=episodes)
    success = np.array([bool(e.final_info.get("is_success")) for e in played])
    final_dist = np.array([-e.info_values["dense_reward"][-1] for e in played])
    agent_obs = [np.asarray(e.obs[:-1], np.float32) for e in played]
    expert_obs = [np.asarray(t.obs[:-1], np.float32) for t in held_out]
    demo_obs = [np.asarray(t.obs[:-1], np.float32) for t in demos]
    closest = np.array([-max(e.info_values["dense_reward"]) for e in played])
    holding = np.array([bool(e.info_values["grasped"][-1]) for e in played])
    air = np.array([e.obs[0][27] - e.obs[0][5] > 0.01 for e in played])  # the goal above the resting block
    out: dict[str, object] = {
        "agent_success": float(success.mean()),
        "agent_final_distance_median_m": round(float(np.median(final_dist)), 4),
        "agent_closest_distance_median_m": round(float(np.median(closest)), 4),
        "agent_holding_at_end": float(holding.mean()),
        "agent_success_goal_in_air": round(float(success[air].mean()), 3) if air.any() else None,
        "agent_success_goal_on_table": round(float(success[~air].mean()), 3) if (~air).any() else None}
    print(f"{run}: {out}", flush=True)
    for view_name, view in (("relative", relative_view), ("placing", placing_view),
                            ("distances", distances_view), ("log_distances", log_distances_view)):
        feats = [view(torch.as_tensor(o)) for o in demo_obs]
        cat = torch.cat(feats)
        mean, std = cat.mean(0), cat.std(0).clamp_min(1e-6)
        demo = torch.nn.utils.rnn.pad_sequence([(f - mean) / std for f in feats], batch_first=True)
        lengths = torch.tensor([len(f) for f in feats])

        def score(eps: list[np.ndarray], cost: str, time_weight: float) -> np.ndarray:
            x = [(view(torch.as_tensor(o)) - mean) / std for o in eps]  # noqa: B023  (used within the loop)
            agent = torch.nn.utils.rnn.pad_sequence(x, batch_first=True)
            sizes = torch.tensor([len(f) for f in x])
            mask = torch.arange(agent.shape[1])[None, :] < sizes[:, None]
            whole = torch.ones(len(x), dtype=torch.bool)
            dmask = window_mask(lengths, torch.zeros(len(x), dtype=torch.long), sizes, whole,  # noqa: B023
                                demo.shape[1])  # noqa: B023
            times = torch.arange(agent.shape[1])[None, :].expand(len(x), -1)
            rews, _ = ot_step_rewards(agent, mask, demo, dmask, epsilon=0.05, iterations=50, top_k=1, scale=1.0,  # noqa: B023
                                      metric=cost, agent_times=times, time_weight=time_weight,
                                      demo_lengths=lengths)  # noqa: B023
            return np.array([float(r[:n].mean()) for r, n in zip(rews, sizes.tolist(), strict=True)])

        for cost in ("cosine", "euclidean"):
            for time_weight in (0.0, 1.0):
                agent_r, expert_r = score(agent_obs, cost, time_weight), score(expert_obs, cost, time_weight)
                row = {"held_out_expert": round(float(expert_r.mean()), 4),
                       "agent_success": round(float(agent_r[success].mean()), 4) if success.any() else None,
                       "agent_failed": round(float(agent_r[~success].mean()), 4) if (~success).any() else None,
                       "failed_below_expert_share": round(float((agent_r[~success] < expert_r.min()).mean()), 3)
                       if (~success).any() else None,
                       "rho_reward_vs_closeness": round(spearman(agent_r, -final_dist), 3)}
                name = f"{view_name}/{cost}/time{time_weight:g}"
                out[name] = row
                print(f"{name:30s} {row}", flush=True)
    return out


if __name__ == "__main__":
    main()
