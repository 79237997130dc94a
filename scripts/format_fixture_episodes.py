"""The small demonstrations behind the format fixtures (tests/data/formats), made with numpy alone so that every
fixture script can import this file in its own virtual environment.

Each episode: a gripper at `eef` (3-D) reaches an object (phase 0), then carries it to a goal (phase 1); the
action is the clipped step towards the current target plus a gripper command (-1 open, 1 closed).
"""

from __future__ import annotations

import numpy as np

EPISODES = 3
"""how many episodes every fixture holds"""


def episodes(seed: int = 0) -> list[dict[str, np.ndarray]]:
    """Per episode: `eef` (T + 1, 3), `object` (T + 1, 4: position and a constant id), `actions` (T, 4),
    `rewards` (T,), `phase` (T + 1,) int64 oracle labels."""
    rng = np.random.default_rng(seed)
    out = []
    for i in range(EPISODES):
        eef = rng.uniform(-0.2, 0.2, 3)
        obj = rng.uniform(0.3, 0.5, 3)
        goal = rng.uniform(-0.5, -0.3, 3)
        held = False
        eefs, objs, acts, phases = [eef.copy()], [obj.copy()], [], [0]
        for _ in range(14 + 2 * i):
            target = goal if held else obj
            step = np.clip(target - eef, -0.1, 0.1)
            eef = eef + step
            if held:
                obj = eef.copy()
            if not held and np.linalg.norm(obj - eef) < 1e-6:
                held = True
            acts.append(np.concatenate([step, [1.0 if held else -1.0]]))
            eefs.append(eef.copy())
            objs.append(obj.copy())
            phases.append(int(held))
        out.append({
            "eef": np.asarray(eefs, np.float64),
            "object": np.concatenate([np.asarray(objs), np.full((len(objs), 1), float(i))], axis=1),
            "actions": np.asarray(acts, np.float64),
            "rewards": -np.linalg.norm(np.asarray(objs)[1:] - goal, axis=1),
            "phase": np.asarray(phases, np.int64),
        })
    return out
