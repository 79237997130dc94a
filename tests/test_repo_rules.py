"""Rules of the repository itself: modules stay readable in size, and nothing edits the import path by hand."""

from __future__ import annotations

import re
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def test_no_source_module_is_over_500_lines() -> None:
    long = {str(p.relative_to(ROOT)): n for p in sorted((ROOT / "src").rglob("*.py"))
            if (n := len(p.read_text().splitlines())) > 500}
    assert not long, f"split these by concept: {long}"


def test_tests_benchmarks_and_scripts_never_edit_sys_path() -> None:
    """A harness is imported from its file (tests/conftest.py's `repo_module`) or run as a script, whose own folder
    Python already searches; an inserted folder would let its short module names shadow installed ones."""
    edit = re.compile(r"sys\.path\.(insert|append)\(")
    found = [str(p.relative_to(ROOT)) for folder in ("tests", "benchmarks", "scripts")
             for p in sorted((ROOT / folder).rglob("*.py"))
             if edit.search(p.read_text()) and p.name != Path(__file__).name]
    assert not found, found


def test_benchmarks_results_holds_only_what_the_docs_publish() -> None:
    """benchmarks/results/ is the published record: each file there is named by the README, a docs page (the
    experiment logs aside), benchmarks/README.md or the benchmark that writes it; one-off studies keep theirs in
    benchmarks/studies/results/."""
    pages = [ROOT / "README.md", ROOT / "Makefile", ROOT / "benchmarks" / "README.md",
             *(p for p in (ROOT / "docs").rglob("*.md") if "experiments" not in p.relative_to(ROOT / "docs").parts[0]),
             *(ROOT / "benchmarks").glob("*.py")]
    text = "\n".join(p.read_text() for p in pages)
    results = ROOT / "benchmarks" / "results"
    # the files of each benchmark's folder and the figures (run folders, sweeps and videos are cited as folders)
    folders = [results, *(d for d in results.iterdir() if d.is_dir() and d.name not in {"runs", "sweeps", "videos"})]
    files = [p for d in folders for p in d.iterdir() if p.is_file()]
    unnamed = [str(p.relative_to(results)) for p in sorted(files) if p.name not in text]
    assert not unnamed, f"move these to benchmarks/studies/results/ or cite them: {unnamed}"


FITTED_OR_CLOSED_LOOP = re.compile(r"compose_order\(|evaluate_policy\(|play_episodes\(|build_trainer\(|pretrain\("
                                   r"|segment_many\(|\.learn\(|\bevaluate\(|\.train\(")
"""calls whose numbers come from a fitted model or a closed-loop rollout"""
FLOAT_ASSERT = re.compile(r"assert [^\n]*(?:[<>]=?\s*-?\d*\.\d|approx\(|allclose\(|isclose\()|assert_close\(")
"""an assertion that compares floats"""


def test_kernel_tests_hold_every_float_check_of_a_fitted_model() -> None:
    """`make test-kernels` (the Makefile's KERNEL_TESTS, run under torch's portable and AVX2 kernels) holds every
    test module that compares floats from fitted models or closed-loop rollouts: such a test can pass on one CPU
    and fail on another, and that is where it shows."""
    makefile = (ROOT / "Makefile").read_text()
    block = makefile.split("KERNEL_TESTS :=", 1)[1].split("\ntest-kernels", 1)[0]
    listed = set(re.findall(r"tests/test_\w+\.py", block))
    missing = [f"tests/{p.name}" for p in sorted((ROOT / "tests").glob("test_*.py"))
               if FITTED_OR_CLOSED_LOOP.search(text := p.read_text()) and FLOAT_ASSERT.search(text)
               and f"tests/{p.name}" not in listed]
    assert not missing, f"compare floats of fitted models but are not in the Makefile's KERNEL_TESTS: {missing}"
