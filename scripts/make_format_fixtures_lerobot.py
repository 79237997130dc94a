"""Write the LeRobot fixture (tests/data/formats/lerobot) with LeRobot's own code, or check an exported copy.

Runs in its own virtual environment, not digail's (LeRobot needs Python >= 3.12 and its own torch):

    python3.12 -m venv runs/venv_lerobot && runs/venv_lerobot/bin/pip install lerobot==0.6.1
    runs/venv_lerobot/bin/python scripts/make_format_fixtures_lerobot.py            # writes the fixture
    runs/venv_lerobot/bin/python scripts/make_format_fixtures_lerobot.py --check DIR  # loads a digail export

Writing: `LeRobotDataset.create`, `add_frame` per frame, `save_episode` per episode, `finalize`; no cameras (so
no videos). Checking: `LeRobotDataset(repo_id, root=DIR)` loads the copy digail exported and every frame's
`subtask_index` is printed per episode, with the names in `meta/subtasks.parquet`.
"""

from __future__ import annotations

import argparse
import importlib.metadata
import json
import shutil
import sys
from pathlib import Path

import numpy as np

# run as a script, so its own folder (scripts/) is already where imports look
from format_fixture_episodes import episodes

OUT = Path(__file__).resolve().parents[1] / "tests" / "data" / "formats" / "lerobot"
REPO_ID = "digail/format-fixture"


def write() -> None:
    from lerobot.datasets.lerobot_dataset import LeRobotDataset

    if OUT.exists():
        shutil.rmtree(OUT)
    features = {
        "observation.state": {"dtype": "float32", "shape": (3,), "names": ["x", "y", "z"]},
        "observation.environment_state": {"dtype": "float32", "shape": (4,), "names": None},
        "action": {"dtype": "float32", "shape": (4,), "names": ["dx", "dy", "dz", "gripper"]},
        "next.reward": {"dtype": "float32", "shape": (1,), "names": None},
    }
    ds = LeRobotDataset.create(REPO_ID, fps=10, features=features, root=OUT, robot_type="point",
                               use_videos=False)
    for ep in episodes():
        # LeRobot stores one row per frame: the state and the action taken in it; the state after the last
        # action is not stored
        for t in range(len(ep["actions"])):
            ds.add_frame({"observation.state": ep["eef"][t].astype(np.float32),
                          "observation.environment_state": ep["object"][t].astype(np.float32),
                          "action": ep["actions"][t].astype(np.float32),
                          "next.reward": np.array([ep["rewards"][t]], np.float32),
                          "task": "pick the object and carry it to the goal"})
        ds.save_episode()
    ds.finalize()
    versions = {name: importlib.metadata.version(name) for name in ("lerobot", "pyarrow", "datasets", "numpy")}
    (OUT.parent / "lerobot.versions.json").write_text(json.dumps(
        {"written_by": "scripts/make_format_fixtures_lerobot.py", "python": sys.version.split()[0], **versions},
        indent=2) + "\n")
    print(f"wrote {OUT} with {versions}")


def check(folder: Path) -> None:
    import pandas as pd
    from lerobot.datasets.lerobot_dataset import LeRobotDataset

    ds = LeRobotDataset(REPO_ID, root=folder)
    names = pd.read_parquet(folder / "meta" / "subtasks.parquet")
    per_episode: dict[int, list[int]] = {}
    for i in range(len(ds)):
        item = ds[i]
        per_episode.setdefault(int(item["episode_index"]), []).append(int(item["subtask_index"]))
    print(json.dumps({"lerobot": importlib.metadata.version("lerobot"), "frames": len(ds),
                      "features": sorted(ds.meta.features),
                      "subtasks": {str(k): int(v) for k, v in names["subtask_index"].items()},
                      "subtask_index": {str(k): v for k, v in per_episode.items()}}))


if __name__ == "__main__":
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--check", type=Path, help="load this exported dataset with LeRobotDataset instead")
    args = parser.parse_args()
    check(args.check) if args.check else write()
