"""How much does a trained off-policy run's policy act on q's code, and how are the codes used?

    python benchmarks/studies/code_dependence.py RUN... [--states 20000] [--out FILE]

For each run folder (a `digail train --train.learner sac` run with its checkpoint.pt), on the last `--states`
transitions of its replay buffer (the states the policy visits late in training, normalised as stored):

- code_share: the fraction of those transitions under each code, and switch_rate the fraction whose next code
  differs from the current one (q's closed-loop choice);
- action_spread_across_codes: per state, the standard deviation over the K codes of pi's mean action clipped to
  the env's bounds (what the env would execute), averaged over states and action dimensions;
- policy_std: pi's own action noise (its state-independent standard deviation), to compare the spread with, and
  log_std its logarithm per action dimension;
- mean_outside_bounds: the fraction of mean-action components beyond the bounds (the clip decides them).

A spread well above the policy's own noise means the policy acts differently per code at the same state: each code's
behaviour is learned from its own share of the transitions. Writes JSON to `--out` (default: stdout only).
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import gymnasium as gym
import numpy as np
import torch

from digail.checkpoint import load_model, load_training_state


def code_dependence(run: Path, states: int) -> dict[str, object]:
    """The measures of the module docstring for one run folder."""
    model, meta = load_model(run)
    state = load_training_state(run / "checkpoint.pt")
    model.load_state_dict(state["model"])  # the weights that acted on the buffer's last transitions
    buf = state["offpolicy"]["buffer"]
    obs = buf["obs"][-states:].float()
    codes, next_codes = buf["codes"][-states:].long(), buf["next_codes"][-states:].long()
    K = int(meta["codes"])
    space = gym.make(meta["env_id"]).action_space
    low, high = (torch.as_tensor(v, dtype=torch.float32) for v in (space.low, space.high))
    eye = torch.eye(K)
    with torch.no_grad():
        means = torch.stack([model.pi.mode(obs, eye[k].expand(len(obs), K)) for k in range(K)])  # (K, n, A)
    own = means[codes, torch.arange(len(obs))]
    return {
        "run": str(run),
        "global_step": int(state["global_step"]),
        "states": len(obs),
        "codes": K,
        "code_share": (torch.bincount(codes, minlength=K).float() / len(codes)).tolist(),
        "switch_rate": float((codes != next_codes).float().mean()),
        "action_spread_across_codes": float(means.clamp(low, high).std(0).mean()) if K > 1
        else 0.0,
        "policy_std": float(model.pi.log_std.detach().exp().mean()),
        "log_std": model.pi.log_std.detach().tolist(),
        "mean_outside_bounds": float(((own < low) | (own > high)).float().mean()),
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("runs", nargs="+", type=Path)
    parser.add_argument("--states", type=int, default=20000)
    parser.add_argument("--out", type=Path)
    args = parser.parse_args()
    torch.set_num_threads(1)
    rows = [code_dependence(run, args.states) for run in args.runs]
    for r in rows:
        print(f"{r['run']} @ {r['global_step']}: share {np.round(r['code_share'], 3).tolist()}, switch "
              f"{r['switch_rate']:.3f}, spread {r['action_spread_across_codes']:.3f} vs pi std {r['policy_std']:.3f}, "
              f"outside bounds {r['mean_outside_bounds']:.3f}")
    if args.out:
        args.out.write_text(json.dumps({"states": args.states, "runs": rows}, indent=1) + "\n")


if __name__ == "__main__":
    main()
