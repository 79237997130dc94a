"""The README's quick start and Python example are executed, so they cannot rot."""

from __future__ import annotations

import json
import re
from pathlib import Path

from digail.cli import main

ROOT = Path(__file__).resolve().parents[1]
README = (ROOT / "README.md").read_text()


def test_quick_start_shows_the_two_commands_first():
    quick = README.split("## Quick start", 1)[1].split("##", 1)[0]
    commands = re.findall(r"^make (\w+)", quick, flags=re.M)
    assert commands[:2] == ["demo", "test"]
    makefile = (ROOT / "Makefile").read_text()
    assert re.search(r"^demo:.*\n\t.*digail run", makefile, flags=re.M)
    assert re.search(r"^test:.*\n\t.*pytest", makefile, flags=re.M)
    assert "make test" in (ROOT / ".ci" / "run").read_text()


def test_make_demo_smoke_variant(tmp_path):
    """`make demo` runs `digail run`; the same pipeline on SMOKE settings, end to end."""
    out = tmp_path / "run"
    assert main(["run", "--preset", "smoke", "--episodes", "3", "--out", str(out)]) == 0
    for name in ("model.pt", "vae/model.pt", "eval.json", "segmentation.json", "compose.json", "report.html",
                 "figures/learning_curves.png", "figures/generated.png", "figures/compose.png",
                 "videos/closed_loop.mp4", "videos/closed_loop.gif"):
        assert (out / name).exists(), name
    ev = json.loads((out / "eval.json").read_text())
    assert ev["episodes"] == 3 and "order_correct_rate" in ev
    assert "Evaluation" in (out / "report.html").read_text()  # opened in Chromium by tests/test_viz_report.py


def test_python_api_example_runs():
    block = README.split("## Python API", 1)[1].split("```python", 1)[1].split("```", 1)[0]
    namespace: dict = {}
    exec(compile(block, "README.md", "exec"), namespace)
    assert len(namespace["codes"]) == 20
    assert namespace["mine"].acts.shape == (10, 2)
