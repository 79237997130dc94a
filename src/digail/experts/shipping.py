"""Shipping a finished expert into the package: its weights and its evaluation in `weights/EXPERTS.json`."""

from __future__ import annotations

import json
import shutil
from pathlib import Path
from typing import Any

from digail.errors import UserError
from digail.experts.actor import load_expert_actor
from digail.experts.recipes import WEIGHTS_DIR, shipped_expert_path
from digail.fsio import write_json

RECORD_FILE = WEIGHTS_DIR / "EXPERTS.json"
"""What ships in `weights/`: per env, the expert's 50-episode evaluation and how it was made."""


def _read_record() -> dict[str, Any]:
    return json.loads(RECORD_FILE.read_text()) if RECORD_FILE.is_file() else {}


def record_expert(env_id: str, entry: dict[str, Any]) -> None:
    """Set `env_id`'s entry in `weights/EXPERTS.json` (keys kept sorted so diffs stay small)."""
    record = _read_record()
    record[env_id] = entry
    write_json(RECORD_FILE, dict(sorted(record.items())))
    RECORD_FILE.chmod(0o644)


def shipped_expert_eval(env_id: str) -> dict[str, Any] | None:
    """The recorded evaluation (50 fresh episodes) of the expert shipped for `env_id`, if any."""
    entry = _read_record().get(env_id)
    return None if entry is None else entry.get("eval")


def _command_path(folder: Path) -> str:
    """`folder` as written in a recorded command: relative to the working directory when it lies below it."""
    try:
        return folder.resolve().relative_to(Path.cwd().resolve()).as_posix()
    except ValueError:
        return folder.as_posix()


def ship_expert(env_id: str, folder: str | Path) -> Path:
    """Copy a finished run's `best_expert.pt` into the package and record its `eval.json` in EXPERTS.json.

    Raises:
        UserError: the folder holds no finished run (no eval.json) or a run for another env.
    """
    folder = Path(folder)
    if not (folder / "eval.json").is_file() or not (folder / "best_expert.pt").is_file():
        raise UserError(f"{folder} holds no finished expert run (eval.json and best_expert.pt); finish it "
                        f"with `digail expert {env_id} --out {folder} --resume` first.")
    result = json.loads((folder / "eval.json").read_text())
    _, meta = load_expert_actor(env_id, folder / "best_expert.pt")  # refuses another env's expert
    dest = shipped_expert_path(env_id)
    dest.parent.mkdir(parents=True, exist_ok=True)
    shutil.copyfile(folder / "best_expert.pt", dest)
    seed = meta.get("seed", 0)
    config = json.loads((folder / "config.json").read_text()) if (folder / "config.json").is_file() else {}
    record_expert(env_id, {
        "file": dest.name,
        "kind": "rl",
        "algo": f"{meta.get('algo', 'ppo')} (stable-baselines3)",
        "command": f"digail expert {env_id} --out {_command_path(folder)} --seed {seed}",
        "eval": {k: result[k] for k in ("episodes", "seed", "mean", "std", "min", "max", "mean_length")}
        | {"deterministic": True},
        "expert_steps": meta.get("steps"),
        "total_steps": result.get("total_steps"),
        "budget_steps": config.get("steps"),
        "wall_s": result.get("wall_s"),
        "target": result.get("target"),
        "reached_target": result.get("reached_target"),
    })
    return dest
