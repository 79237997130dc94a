"""The code blocks of the guides run, so the documentation cannot rot.

Every ```python and ```bash block of the guide pages (GUIDES) runs, page by page in its own temporary folder:
python blocks share one namespace per page; a python block titled with a file name (```python title="x.py") is
written to that file instead (later blocks import it); each line of a bash block is `digail ...` (run through
`digail.cli.main`, which must return 0) or `python FILE ARGS` (a file an earlier block wrote). A block that is too
expensive for the tests carries `<!-- skip: reason -->` on the line before it: it is reported as a skipped test
with that reason, never dropped silently. A bash line of any other form fails the test: run it or mark the block.
"""

from __future__ import annotations

import re
import runpy
import shlex
import sys
from dataclasses import dataclass
from pathlib import Path

import pytest

from digail.cli import main

ROOT = Path(__file__).resolve().parents[1]
DOCS = ROOT / "docs"
GUIDES = sorted([DOCS / "getting-started.md", DOCS / "api.md", DOCS / "concepts.md", *DOCS.glob("howto/*.md")])
"""pages whose code blocks run; results, the measurement log and the design quote commands that take hours"""

FENCE = re.compile(r"^```(\w+)([^\n]*)\n(.*?)^```\s*$", re.M | re.S)
SKIP = re.compile(r"<!--\s*skip:\s*(.*?)\s*-->\s*$", re.S)


@dataclass(frozen=True)
class Block:
    page: Path
    line: int
    lang: str
    title: str | None
    code: str
    skip: str | None

    @property
    def where(self) -> str:
        return f"{self.page.relative_to(ROOT)}:{self.line}"


def blocks(page: Path) -> list[Block]:
    """The python and bash blocks of `page`, with their title and skip reason (None: the block runs)."""
    text = page.read_text()
    found = []
    for m in FENCE.finditer(text):
        lang = m.group(1)
        if lang not in ("python", "bash"):
            continue
        before = text[:m.start()].rstrip("\n").rsplit("\n", 1)[-1]
        skip = SKIP.search(before)
        title = re.search(r'title="([^"]+)"', m.group(2))
        found.append(Block(page, text.count("\n", 0, m.start()) + 1, lang, title.group(1) if title else None,
                           m.group(3), skip.group(1) if skip else None))
    return found


def bash_lines(code: str) -> list[str]:
    """The commands of a bash block: continuation lines joined, comments and blank lines dropped."""
    joined = code.replace("\\\n", " ")
    lines = [ln for ln in joined.splitlines() if ln.strip() and not ln.lstrip().startswith("#")]
    return [ln.split(" #", 1)[0].strip() for ln in lines]


def run_block(block: Block, namespace: dict) -> None:
    if block.lang == "python" and block.title:
        Path(block.title).write_text(block.code)
        return
    if block.lang == "python":
        exec(compile(block.code, block.where, "exec"), namespace)
        return
    for line in bash_lines(block.code):
        argv = shlex.split(line)
        if argv[0] == "digail":
            assert main(argv[1:]) == 0, f"{block.where}: {line}"
        elif argv[0] == "python" and len(argv) > 1 and Path(argv[1]).is_file():
            old = sys.argv
            sys.argv = argv[1:]
            try:
                runpy.run_path(argv[1], run_name="__main__")
            except SystemExit as done:
                assert done.code in (0, None), f"{block.where}: {line} exited with {done.code}"
            finally:
                sys.argv = old
        else:
            pytest.fail(f"{block.where}: cannot run {line!r}; run it another way or put "
                        "`<!-- skip: reason -->` before the block")


ALL = [b for page in GUIDES for b in blocks(page)]


@pytest.mark.parametrize("page", [p for p in GUIDES if any(not b.skip for b in blocks(p))],
                         ids=lambda p: str(p.relative_to(DOCS)))
def test_guide_runs(page, tmp_path, monkeypatch):
    """Every block of the page not marked skip runs, in order, in a fresh folder."""
    monkeypatch.chdir(tmp_path)
    monkeypatch.syspath_prepend(str(tmp_path))
    namespace: dict = {"__name__": "__docs__"}
    for block in blocks(page):
        if block.skip is None:
            run_block(block, namespace)


@pytest.mark.parametrize("block", [b for b in ALL if b.skip], ids=lambda b: b.where)
def test_skipped_block(block):
    """A block marked skip (too long to run here) is still read: its Python compiles and each `digail` line names a
    command digail has, so a renamed command or a broken snippet shows here rather than in a reader's shell."""
    from digail.cli import COMMANDS

    if block.lang == "python":
        compile(block.code, block.where, "exec")
        return
    for line in bash_lines(block.code):
        argv = shlex.split(line)
        if argv[0] != "digail":
            continue
        assert argv[1] in COMMANDS, f"{block.where}: `digail {argv[1]}` is no command of digail's"


def test_every_skip_has_a_reason_and_guides_have_blocks():
    assert GUIDES and all(p.exists() for p in GUIDES)
    for b in ALL:
        assert b.skip is None or len(b.skip) > 10, f"{b.where}: say why the block is skipped"
    assert sum(b.skip is None for b in ALL) >= 5


def test_block_parser(tmp_path):
    page = tmp_path / "page.md"
    page.write_text('text\n\n<!-- skip: needs a GPU for hours -->\n```bash\ndigail run \\\n  --preset smoke  # x\n```\n'
                    '```python title="m.py"\nX = 1\n```\n```text\nignored\n```\n```python\nimport m\n```\n')
    found = blocks(page)
    assert [(b.lang, b.title, b.skip) for b in found] == [
        ("bash", None, "needs a GPU for hours"), ("python", "m.py", None), ("python", None, None)]
    assert bash_lines(found[0].code) == ["digail run    --preset smoke"]
