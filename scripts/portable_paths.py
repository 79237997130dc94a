"""Rewrite the absolute paths of the machines the committed results were made on, so every published command and
run folder reads the same on any checkout.

    python scripts/portable_paths.py            # rewrites the tracked files (text, and model.pt's stored config)
    python scripts/portable_paths.py --check    # lists the files that still hold such a path, exit 1 if any

A path inside a checkout of the repository (the main one or a worktree beside it) becomes relative to the
repository, a scratch folder under the system's temporary folder becomes one under `runs/` (untracked), and the
robosuite producer's own venv and data folders, which live outside any checkout, become `$RSVENV` and `$RSDATA`.
tests/test_portable_paths.py guards the result.
"""

from __future__ import annotations

import argparse
import io
import json
import re
import subprocess
import sys
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parents[1]

MACHINE_PATH = re.compile(r"(?<![\w.:/$~-])/(?:work|tmp|root|home|Users)/")
"""the start of an absolute path on the machines the results were made on (a URL's path does not match)"""

REWRITES: list[tuple[re.Pattern[str], str]] = [(re.compile(a), b) for a, b in [
    # checkouts of the repository: the main one and worktrees beside it, where every command ran from the root
    (r"/work/main/", ""), (r"/work/main\b", "."),
    (r"/work/wt/[\w.-]+/", ""), (r"/work/wt-[\w.-]+/", ""), (r"/work/wt-[\w.-]+\b", "."),
    (r"/work/exp\d*/runs/", "runs/"),
    # the robosuite producer's environment (its own venv: mujoco <= 3.9, numpy < 2) and its data, outside the repo
    (r"/work/rsvenv\b", "$RSVENV"), (r"/work/rsdata\b", "$RSDATA"),
    # scratch folders
    (r"(?<![\w.:/$~-])/tmp/", "runs/"),
]]


def portable(text: str) -> str:
    """`text` with every known machine path rewritten (see the module docstring)."""
    for pattern, repl in REWRITES:
        text = pattern.sub(lambda _m, r=repl: r, text)
    return text


def tracked_files() -> list[Path]:
    """The repository's tracked files (git), else every file outside the ignored folders."""
    try:
        out = subprocess.run(["git", "-C", str(ROOT), "ls-files", "-z"], check=True, capture_output=True).stdout
        return [ROOT / p for p in out.decode().split("\0") if p]
    except (OSError, subprocess.CalledProcessError):
        skip = {".git", ".venv", "runs", "site", "__pycache__", ".pytest_cache", ".mypy_cache", ".ruff_cache"}
        return [p for p in ROOT.rglob("*") if p.is_file() and not skip & set(p.relative_to(ROOT).parts)]


def checkpoint_strings(obj: Any) -> list[str]:
    """Every string inside a loaded checkpoint (its stored config included), keys too."""
    if isinstance(obj, str):
        return [obj]
    if isinstance(obj, dict):
        return [s for k, v in obj.items() for s in (*checkpoint_strings(k), *checkpoint_strings(v))]
    if isinstance(obj, list | tuple):
        return [s for v in obj for s in checkpoint_strings(v)]
    return []


def _map_strings(obj: Any) -> Any:
    if isinstance(obj, str):
        return portable(obj)
    if isinstance(obj, dict):
        return {k: _map_strings(v) for k, v in obj.items()}
    if isinstance(obj, list):
        return [_map_strings(v) for v in obj]
    if isinstance(obj, tuple):
        return tuple(_map_strings(v) for v in obj)
    return obj


def rewrite_checkpoint(path: Path) -> bool:
    """Rewrite the strings of a weights-only checkpoint in place (its tensors are saved again untouched)."""
    import torch

    payload = torch.load(path, map_location="cpu", weights_only=True)
    if not any(MACHINE_PATH.search(s) for s in checkpoint_strings(payload)):
        return False
    buf = io.BytesIO()
    torch.save(_map_strings(payload), buf)
    path.write_bytes(buf.getvalue())
    return True


def offenders(files: list[Path]) -> list[str]:
    """The files (repository-relative) that still hold a machine path, with the first one found."""
    import torch

    found = []
    for path in files:
        if path.name in {"portable_paths.py", "test_portable_paths.py"} or not path.is_file():
            continue
        if path.suffix == ".pt":
            strings = checkpoint_strings(torch.load(path, map_location="cpu", weights_only=True))
        else:
            data = path.read_bytes()
            if b"\0" in data[:8192]:
                continue
            strings = [data.decode("utf-8", errors="replace")]
        for s in strings:
            if m := MACHINE_PATH.search(s):
                found.append(f"{path.relative_to(ROOT)}: {s[m.start():m.start() + 60].splitlines()[0]}")
                break
    return found


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--check", action="store_true", help="only list the files that hold a machine path")
    args = parser.parse_args()
    files = tracked_files()
    if not args.check:
        for path in files:
            if path.name in {"portable_paths.py", "test_portable_paths.py"} or not path.is_file():
                continue
            if path.suffix == ".pt":
                if rewrite_checkpoint(path):
                    print(f"rewrote {path.relative_to(ROOT)}")
                continue
            data = path.read_bytes()
            if b"\0" in data[:8192]:
                continue
            text = data.decode("utf-8")
            new = portable(text)
            if new != text:
                if path.suffix == ".json":
                    json.loads(new)  # still JSON
                path.write_text(new)
                print(f"rewrote {path.relative_to(ROOT)}")
    left = offenders(files)
    print("\n".join(left))
    sys.exit(1 if left and args.check else 0)


if __name__ == "__main__":
    main()
