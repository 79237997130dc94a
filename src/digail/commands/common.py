"""What several commands share: run folders, reading a run's environment, and terminal summaries."""

from __future__ import annotations

import argparse
import json
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from digail.config import Preset, get_preset
from digail.errors import UserError
from digail.utils import check_new_dir, default_run_dir


def new_run_dir(out: Path | None, env_id: str, method: str, seed: int, force: bool) -> Path:
    """The run folder `out`, or `runs/<env>__<method>__s<seed>__<time>`; refuses an existing one without `force`."""
    run_dir = Path(out) if out is not None else default_run_dir(env_id, method, seed)
    check_new_dir(run_dir, force)
    return run_dir


def run_env_id(run: Path, meta: dict[str, Any]) -> str:
    """The environment a run was trained on: its model.pt's record, else its config.json's."""
    env_id = meta.get("env_id")
    if not env_id:
        cfg = Path(run) / "config.json"
        if cfg.exists():
            env_id = json.loads(cfg.read_text()).get("env_id")
    if not env_id:
        raise UserError(f"cannot tell which environment {run} was trained on; its model.pt and config.json "
                        "name none.")
    return str(env_id)


def print_eval_summary(result: dict[str, Any]) -> None:
    """One line of an evaluation's (or a composition's) headline numbers."""
    keys = ["mean_return", "std_return", "normalized_return", "success_rate", "path_length_ratio",
            "order_correct_rate", "order_reversed_rate", "radius_error"]
    parts = [f"{k}={result[k]:.3f}" for k in keys if isinstance(result.get(k), float)]
    print(f"{result['episodes']} episodes: " + ", ".join(parts))


def preset_from_argv(argv: Sequence[str]) -> tuple[Preset, str, str]:
    """The preset a command line asks for (--preset, else the one of --env or of the dataset's env), with the env
    id and the --demos value it found; lets the nested configs' defaults start from the preset."""
    pre = argparse.ArgumentParser(add_help=False)
    pre.add_argument("--preset", default=None)
    pre.add_argument("--env", default="")
    pre.add_argument("--demos", default="")
    known, _ = pre.parse_known_args(list(argv))
    env_id = known.env
    if not env_id and known.demos:
        from digail.data.minari_io import dataset_env_id

        try:
            env_id = dataset_env_id(known.demos)
        except UserError:
            env_id = ""  # reported properly by the command itself
    return get_preset(known.preset, env_id), env_id, known.demos
