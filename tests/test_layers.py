"""The import layers of docs/design.md hold (import-linter's contract in pyproject.toml): a new cycle fails CI."""

from __future__ import annotations

import shutil
import subprocess
import sys
from pathlib import Path
from typing import Any

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


def _param_path() -> object:
    import importlib.util

    spec = importlib.util.spec_from_file_location("param_path", ROOT / "scripts" / "param_path.py")
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    sys.modules["param_path"] = module  # its dataclasses look their module up there
    spec.loader.exec_module(module)
    return module


def test_a_preset_value_climbs_once_on_its_way_to_the_trainer() -> None:
    """`--train.bonus-weight` (scripts/param_path.py): read from the preset in `config`, it climbs once, to the
    command's defaults, and the parse hands it down from there (no trip back up through the registry or `cli`);
    from there it goes down to the trainer the command builds. (The static walk ends there: the trainer hands itself
    to its learner through the learner registry, a call it does not follow, and the learner asks for the reward
    that reads the value.)"""
    pp: Any = _param_path()
    index = pp.Index()
    path = pp.path_of(index, "train", ("train", "bonus_weight"))
    files, climbs = pp.summary(path, pp.layers())
    assert path[0] == "digail.preset.get_preset" and path[-1] == "digail.algos.gail.trainer.GAIL.__init__"
    assert "digail.cli._main" not in path and not any(q.startswith("digail.envs.") for q in path), path
    assert (len(files), climbs) == (6, 1), (files, path)


def test_param_path_counts_a_climb_back_to_the_command() -> None:
    """The counting itself: a value passed down and read, then the walk returning to a higher layer."""
    pp: Any = _param_path()
    rank = pp.layers()
    path = ["digail.commands.x.f", "digail.algos.gail.g", "digail.commands.x.f", "digail.algos.ppo.h"]
    files, climbs = pp.summary(path, rank)
    assert climbs == 1 and len(files) == 3
