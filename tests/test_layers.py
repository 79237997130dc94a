"""The import layers of docs/design.md hold (import-linter's contract in pyproject.toml): a new cycle fails CI."""

from __future__ import annotations

import shutil
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]


def test_import_layers_hold() -> None:
    exe = shutil.which("lint-imports", path=str(Path(sys.executable).parent)) or shutil.which("lint-imports")
    if exe is None:
        pytest.fail("lint-imports is missing; install the dev extra (`pip install -e '.[dev]'`).")
    done = subprocess.run([exe, "--no-cache"], cwd=ROOT, capture_output=True, text=True, timeout=300)
    assert done.returncode == 0, done.stdout[-4000:] + done.stderr[-2000:]


def test_import_graph_has_no_circle_and_no_upward_import() -> None:
    """Every import statement counts, lazy ones too (scripts/import_graph.py): no circle anywhere."""
    import importlib.util

    spec = importlib.util.spec_from_file_location("import_graph", ROOT / "scripts" / "import_graph.py")
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    graph = module.grimp.build_graph("digail", cache_dir=None)
    assert module.upward_imports(graph) == []
    assert module.circles(graph) == []
