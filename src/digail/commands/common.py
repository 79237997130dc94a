"""What several commands share: run folders, reading a run's environment, and terminal summaries."""

from __future__ import annotations

import argparse
import json
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from digail.config import Preset
from digail.errors import UserError
from digail.utils import check_new_dir, default_run_dir

CONFIG_SCHEMA = 1
"""version of the `config.json` layout below; bumped when a key changes meaning"""


def path_ref(value: str | Path | None) -> str | None:
    """A dataset or run reference as `config.json` stores it: an existing path made absolute (so a later command
    run from another directory finds it), anything else (a dataset id) as given."""
    if value is None or str(value) == "":
        return None
    path = Path(value)
    return str(path.resolve()) if path.exists() else str(value)


def run_config(*, kind: str, env_id: str | None, demos: str | Path | None, seed: int, preset: str | None = None,
               device: str | None = None, vae: Any = None, train: Any = None, vae_run: str | Path | None = None,
               args: Any = None, **extra: Any) -> dict[str, Any]:
    """The one schema of every run folder's `config.json` (and of the config inside its `model.pt`).

    Keys: `schema`, `kind` ("vae", "digail", "gail"), `method` (the same for trained policies), `env_id`, `demos`
    and `vae_run` (absolute paths or dataset ids, see `path_ref`), `seed`, `preset`, `device`, `digail_version`,
    `vae` and `train` (the resolved `VAEConfig` / `TrainConfig`, or None), `args` (the command's own arguments,
    what `--resume` rebuilds them from) and any command-specific extras.
    """
    from digail.config import to_dict
    from digail.version import __version__

    config: dict[str, Any] = {
        "schema": CONFIG_SCHEMA,
        "kind": kind,
        "method": kind if kind in ("digail", "gail") else None,
        "env_id": env_id,
        "demos": path_ref(demos),
        "vae_run": path_ref(vae_run),
        "seed": seed,
        "preset": preset,
        "device": device,
        "digail_version": __version__,
        "vae": to_dict(vae) if vae is not None else None,
        "train": to_dict(train) if train is not None else None,
        "args": to_dict(args) if args is not None else None,
    }
    config.update(extra)
    return config


def write_run_config(run_dir: Path, config: dict[str, Any]) -> Path:
    """Write `config` (from `run_config`) as RUN/config.json; returns the file."""
    from digail.utils import write_json

    path = Path(run_dir) / "config.json"
    write_json(path, config)
    return path


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
    from digail.envs.registry import preset_for

    return preset_for(env_id, known.preset), env_id, known.demos
