"""MkDocs hook: serve the committed benchmark figures (benchmarks/results/figures/) under `figures/` in the site.

The figures stay where the benchmark scripts write them; the docs link them as `figures/<name>.png` (relative to
the docs folder) and this hook adds them to the build, so nothing is copied into docs/ by hand.
"""

from __future__ import annotations

from pathlib import Path

from mkdocs.structure.files import File, Files

FIGURES = Path(__file__).resolve().parents[1] / "benchmarks" / "results" / "figures"


def on_files(files: Files, config) -> Files:  # noqa: ANN001 - MkDocs' hook signature
    for path in sorted(FIGURES.rglob("*.png")):
        files.append(File.generated(config, f"figures/{path.relative_to(FIGURES).as_posix()}",
                                    abs_src_path=str(path)))
    return files
