"""What several commands share: run folders, reading a run's environment, and terminal summaries."""

from __future__ import annotations

import argparse
import os
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from digail.errors import UserError
from digail.fsio import check_new_dir
from digail.preset import Preset
from digail.utils import default_run_dir, one_line


def new_run_dir(out: Path | None, env_id: str, method: str, seed: int, force: bool,
                resume_command: str | None = None, reads: Sequence[tuple[Path, str]] = ()) -> Path:
    """The run folder `out`, or `runs/<env>__<method>__s<seed>__<time>`; refuses an existing one without `force`
    (naming `digail <resume_command> --resume` when it is an unfinished run of that command), one that is, holds
    or lies inside what the command `reads` (`inputs`), and an output that cannot be written. Creates nothing."""
    run_dir = Path(out) if out is not None else default_run_dir(env_id, method, seed)
    hint = ""
    if resume_command is not None and run_dir.is_dir() and (run_dir / "config.json").is_file():
        hint = f", or continue it with `digail {resume_command} --resume {run_dir}`"
    check_new_dir(run_dir, force, hint, protected=reads)
    return run_dir


def inputs(demos: str | os.PathLike[str] | None = None,
           *more: tuple[str | os.PathLike[str] | None, str]) -> list[tuple[Path, str]]:
    """What a command reads, as the (path, what it is) pairs its output must stay clear of
    (`digail.fsio.check_new_dir`): the demonstrations (a file or folder, or the folder a Minari id names) and the
    `more` pairs (e.g. a VAE run folder); those not given or not found are left out."""
    from digail.data.minari_io import resolve_dataset

    found: list[tuple[Path, str]] = []
    if demos is not None and str(demos) != "":
        path: Path | None = Path(demos)
        if not Path(demos).exists() and not Path(demos).is_symlink():
            try:
                path = resolve_dataset(demos)
            except UserError:  # not a dataset either: nothing on disk to protect
                path = None
        if path is not None:
            found.append((path, "the input demonstrations"))
    found += [(Path(p), what) for p, what in more if p is not None and str(p) != ""]
    return found


def resolve_ref(run: Path, ref: str | Path | None) -> str | None:
    """A dataset or VAE reference read from RUN/config.json: as stored when it is absolute, an id or found from
    here; else relative to the run folder (a run folder moved or used from another working directory)."""
    if ref is None or str(ref) == "":
        return None if ref is None else ""
    path = Path(ref)
    if path.is_absolute() or path.exists() or not (Path(run) / path).exists():
        return str(ref)
    return str((Path(run) / path).resolve())


def saved_args(cls: type, saved: dict[str, Any], run_dir: Path, what: str) -> Any:
    """`cls` rebuilt from the arguments a run folder's config.json recorded (what `--resume` continues with);
    one sentence naming `what` (e.g. "run", "training") when they no longer fit `cls`."""
    from digail.config import from_dict

    try:
        return from_dict(cls, saved)
    except (TypeError, AttributeError) as exc:
        raise UserError(f"the {what} arguments in {run_dir / 'config.json'} are invalid ({type(exc).__name__}); "
                        f"restore the file or start the {what} again.") from None
    except UserError as exc:  # a recorded value its checks refuse: the file's fault, not the command line's
        raise UserError(f"the {what} arguments in {run_dir / 'config.json'} are invalid ({one_line(exc)}); "
                        f"restore the file or start the {what} again.") from None


def check_output_folder(run: Path) -> Path:
    """A run folder an analysis command (evaluate, compose, segment) writes into: it must exist and be writable,
    checked before the rollouts start."""
    from digail.fsio import check_writable

    run = Path(run)
    if not run.is_dir():
        raise UserError(f"run folder {run} does not exist; pass a folder made by `digail pretrain`, `digail train` "
                        "or `digail run`.")
    check_writable(run, "run folder")
    return run


def run_env_id(run: Path, meta: dict[str, Any]) -> str:
    """The environment a run was trained on: its model.pt's record, else its config.json's."""
    from digail.checkpoint import read_config
    from digail.user_envs import register_recorded_env

    config = read_config(run)
    env_id = meta.get("env_id") or config.get("env_id")
    register_recorded_env(config.get("env_spec"))  # an env defined outside digail, made from its entry point
    if not env_id:
        raise UserError(f"cannot tell which environment {run} was trained on; its model.pt and config.json "
                        "name none.")
    return str(env_id)


def print_eval_summary(result: dict[str, Any]) -> None:
    """One line of an evaluation's (or a composition's) headline numbers."""
    from digail.envs.registry import env_spec

    keys = ["mean_return", "std_return", "normalized_return", "success_rate", "path_length_ratio",
            "order_correct_rate", "order_reversed_rate", "radius_error"]
    spec = env_spec(str(result.get("env_id", "")))
    if spec is not None:  # which return mean_return is, then the env's other task measures
        keys += [spec.reward_name] if spec.eval_return is not None else []
        keys += [m.name for m in spec.step_metrics if m.name != spec.eval_return]
    parts = [f"{k}={result[k]:.3f}" for k in keys if isinstance(result.get(k), float)]
    measure = f" (mean_return is the {spec.eval_return})" if spec is not None and spec.eval_return else ""
    print(f"{result['episodes']} episodes{measure}: " + ", ".join(parts))


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
    from digail.envs.registry import env_preset
    from digail.preset import resolve_preset

    # the preset read straight from `config` (the registry gives only its name): its values go from there to the
    # command's defaults and the parse, not back up through the registry
    return resolve_preset(known.preset, env_preset(env_id)), env_id, known.demos
