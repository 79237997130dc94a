"""Why Circle-World's closed-loop order fails: the macro-policy switches only when the agent comes back almost
exactly onto the origin. The numbers behind the README's Circle-World paragraph.

    python benchmarks/studies/circleworld_switch.py RUN [RUN ...] [--episodes 300]

RUN is a `digail pretrain` or `digail train` run on digail/circleworld/expert-v0. For each, prints
1. q's probability of switching to the second code, with the first code as the previous one, on a grid of
   positions around the origin (where the expert switches, after exactly one circle);
2. over `--episodes` deterministic closed-loop episodes (the `digail evaluate` seeds), the agent's closest
   approach to the origin after the first circle (steps 30-90), against whether the order came out right.
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np
import torch

from digail.checkpoint import load_model
from digail.eval.returns import run_episodes
from digail.nets.mlp import one_hot

ENV = "digail/CircleWorld-v0"


@torch.no_grad()
def switch_map(model) -> None:  # type: ignore[no-untyped-def]
    """P(switch | position, previous code = the start code) near the origin."""
    xs, ys = np.linspace(-0.2, 0.2, 9), np.array([0.02, 0.0, -0.02])
    start = int(model.q(model.normalizer(torch.zeros(1, 2)), torch.zeros(1, model.codes)).argmax(-1))
    print(f"  P(switch away from code {start}) near the origin; columns x = " + " ".join(f"{x:+.2f}" for x in xs))
    for y in ys:
        pts = torch.tensor([[x, y] for x in xs], dtype=torch.float32)
        prev = one_hot(torch.full((len(xs),), start), model.codes)
        p = 1 - torch.softmax(model.q(model.normalizer(pts), prev), -1)[:, start]
        print(f"    y = {y:+.2f}:" + "".join(f" {v:5.2f}" for v in p.numpy()))


def closest_approach(model, episodes: int) -> None:  # type: ignore[no-untyped-def]
    eps = run_episodes(model, ENV, episodes, 10_000, deterministic=True, keep_obs=episodes)
    dist = np.array([np.linalg.norm(np.asarray(e.obs)[30:91], axis=1).min() for e in eps])
    ok = np.array([bool(e.final_info["order_correct"]) for e in eps])
    print(f"  order_correct {ok.mean():.3f} over {len(eps)} episodes; closest approach to the origin after the "
          f"first circle: median {np.median(dist[ok]):.3f} where the order is right, "
          f"{np.median(dist[~ok]) if (~ok).any() else float('nan'):.3f} where it is wrong")
    for lo, hi in ((0.0, 0.02), (0.02, 0.03), (0.03, 0.04), (0.04, 0.05), (0.05, np.inf)):
        m = (dist >= lo) & (dist < hi)
        rate = f"{ok[m].mean():.2f}" if m.any() else "  - "
        print(f"    closest in [{lo:.2f}, {hi:.2f}): {m.sum():3d} episodes, order_correct {rate}")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("runs", type=Path, nargs="+")
    parser.add_argument("--episodes", type=int, default=300)
    args = parser.parse_args()
    torch.set_num_threads(1)
    for run in args.runs:
        model, _ = load_model(run / "model.pt")
        print(run)
        switch_map(model)
        closest_approach(model, args.episodes)


if __name__ == "__main__":
    main()
