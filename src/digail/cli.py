"""The `digail` command line: the table of subcommands and `main`.

Each subcommand lives in `digail.commands.<name>` with its argument dataclass (parsed by tyro), the function that
runs it and, where nested configs start from a preset, a `defaults(argv)` function. Bad input raises `UserError`,
printed as one sentence with exit status 2.
"""

from __future__ import annotations

import importlib
import os
import sys
from collections.abc import Sequence
from typing import Any

import tyro

from digail.errors import UserError

COMMANDS: dict[str, tuple[str, str]] = {
    "demos": ("DemosArgs", "demos_command"),
    "pretrain": ("PretrainArgs", "pretrain_command"),
    "segment": ("SegmentArgs", "segment_command"),
    "train": ("TrainArgs", "train_command"),
    "evaluate": ("EvaluateArgs", "evaluate_command"),
    "compose": ("ComposeArgs", "compose_command"),
    "run": ("RunArgs", "run_command"),
    "expert": ("ExpertArgs", "expert_command"),
    "video": ("VideoArgs", "video_command"),
    "report": ("ReportArgs", "report_command"),
}
"""subcommand -> (argument dataclass, function) in the module `digail.commands.<subcommand>`"""


def _command(name: str) -> tuple[Any, Any, Any]:
    """The argument class, the function and the optional `defaults(argv)` of subcommand `name`."""
    module = importlib.import_module(f"digail.commands.{name}")
    args_cls, fn = COMMANDS[name]
    return getattr(module, args_cls), getattr(module, fn), getattr(module, "defaults", None)


def _usage() -> str:
    lines = ["usage: digail COMMAND [ARGS] ...", "",
             "Directed-Info GAIL: sub-task discovery and hierarchical imitation.",
             "", "commands:"]
    width = max(map(len, COMMANDS))
    for name in COMMANDS:
        first = (_command(name)[0].__doc__ or "").strip().splitlines()[0]
        lines.append(f"  {name:<{width}}  {first}")
    lines += ["", "`digail COMMAND --help` shows a command's options."]
    return "\n".join(lines)


def main(argv: Sequence[str] | None = None) -> int:
    """Entry point of the `digail` console script; returns the exit status."""
    argv = list(sys.argv[1:] if argv is None else argv)
    if not argv or argv[0] in ("-h", "--help"):
        print(_usage())
        return 0 if argv else 2
    name, rest = argv[0], argv[1:]
    if name not in COMMANDS:
        print(f"digail: unknown command {name!r}; run `digail --help` for the list.", file=sys.stderr)
        return 2
    os.environ.setdefault("MUJOCO_GL", "egl")
    from digail.utils import set_torch_threads

    set_torch_threads(1)  # small nets: a second thread buys nothing and costs much under load
    cls, handler, defaults = _command(name)
    try:
        default = defaults(rest) if defaults is not None else None
        args = tyro.cli(cls, args=rest, prog=f"digail {name}", default=default, description=cls.__doc__)
        handler(args)
    except UserError as exc:
        print(f"digail {name}: error: {exc}", file=sys.stderr)
        return 2
    except SystemExit as exc:  # tyro / argparse: bad flags exit 2 already, --help exits 0
        return int(exc.code or 0)
    except KeyboardInterrupt:
        print(f"digail {name}: interrupted; a training run can be continued with --resume.", file=sys.stderr)
        return 130
    return 0


if __name__ == "__main__":
    sys.exit(main())
