"""Write the imitation fixtures (tests/data/formats/imitation_*) with imitation's own code.

Runs in its own virtual environment, not digail's (imitation 1.0.1 pins gymnasium 0.29):

    python3.11 -m venv venv-imitation && venv-imitation/bin/pip install torch==2.13.0 imitation==1.0.1
    venv-imitation/bin/python scripts/make_format_fixtures_imitation.py

Writes, from the three episodes of `format_fixture_episodes.py` as imitation's `TrajectoryWithRew` (observation:
gripper and object positions, 7 numbers):

- `imitation_dataset/`: `imitation.data.serialize.save(path, trajectories)`, the HuggingFace datasets folder.
- `imitation_transitions.npz`: `imitation.data.rollout.flatten_trajectories_with_rew(trajectories)` saved with
  `numpy.savez` as obs, acts, next_obs, dones, rews (the pickled infos left out).

Episode 0 ended in a terminal state; episode 1 was cut by a time limit and, as a Stable-Baselines3 vectorised env
records it, is flagged `terminal` with `TimeLimit.truncated` in its last info; episode 2 is not terminal.
"""

from __future__ import annotations

import importlib.metadata
import json
import shutil
import sys
from pathlib import Path

import numpy as np

# run as a script, so its own folder (scripts/) is already where imports look
from format_fixture_episodes import episodes

OUT = Path(__file__).resolve().parents[1] / "tests" / "data" / "formats"


def main() -> None:
    from imitation.data import rollout, serialize
    from imitation.data.types import TrajectoryWithRew

    trajs = []
    for i, ep in enumerate(episodes()):
        obs = np.concatenate([ep["eef"], ep["object"][:, :3]], axis=1).astype(np.float32)
        infos = [{} for _ in ep["actions"]]
        if i == 1:
            infos[-1] = {"TimeLimit.truncated": True}
        trajs.append(TrajectoryWithRew(obs=obs, acts=ep["actions"].astype(np.float32), infos=np.array(infos),
                                       terminal=i < 2, rews=ep["rewards"].astype(np.float32)))
    folder = OUT / "imitation_dataset"
    if folder.exists():
        shutil.rmtree(folder)
    serialize.save(folder, trajs)
    flat = rollout.flatten_trajectories_with_rew(trajs)
    np.savez(OUT / "imitation_transitions.npz", obs=flat.obs, acts=flat.acts, next_obs=flat.next_obs,
             dones=flat.dones, rews=flat.rews)
    versions = {name: importlib.metadata.version(name) for name in ("imitation", "datasets", "pyarrow", "numpy",
                                                                    "gymnasium")}
    (OUT / "imitation.versions.json").write_text(json.dumps(
        {"written_by": "scripts/make_format_fixtures_imitation.py", "python": sys.version.split()[0], **versions},
        indent=2) + "\n")
    print(f"wrote {folder} and {OUT / 'imitation_transitions.npz'} with {versions}")


if __name__ == "__main__":
    main()
