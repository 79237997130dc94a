"""Write the probe table of docs/reference/errors.md from the probes of tests/test_failure_paths_round4.py: each
probe is run in a temporary folder, and what it gets (accepted, or its refusal sentence) goes into the table.

    python scripts/probe_table.py           # (re)write the table between "## Probes"'s paragraph and the API section

A test (`test_the_reliability_page_lists_every_probe`) checks that every probe has its row. Sentences are cut at
about 170 characters and the temporary folder's path is taken out of them, so the table reads the same on any
machine (memory sizes aside).
"""

from __future__ import annotations

import importlib.util
import re
import shutil
import sys
import tempfile
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
PAGE = ROOT / "docs" / "reference" / "errors.md"
CATEGORIES = [("set-", "Sweep overrides (`--set`)"), ("spec-", "Sweep spec files"), ("force-", "`--force`"),
              ("import-", "Imported files"), ("subset-", "Demonstration subsets"), ("cli-", "Demonstration subsets"),
              ("replay-", "Replay buffers in checkpoints"), ("utf8-", "Paths that are not UTF-8"),
              ("lock-", "Lock files"), ("compose-cli", "Analysis commands on a run folder"),
              ("evaluate-", "Analysis commands on a run folder"), ("segment-", "Analysis commands on a run folder"),
              ("report-", "Analysis commands on a run folder"), ("compose-", "Composition schedules"),
              ("resume-", "Resume paths")]
"""probe id prefix -> the table's heading, in the page's order"""
START = "the paths are relative to the probe's folder.\n"
END = "::: digail.errors"


def table() -> str:
    # the probes are a test module; it is loaded from its file rather than by putting tests/ on the import path
    spec = importlib.util.spec_from_file_location("test_failure_paths_round4",
                                                  ROOT / "tests" / "test_failure_paths_round4.py")
    assert spec is not None and spec.loader is not None
    probes = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = probes  # its dataclasses look their module up by name
    spec.loader.exec_module(probes)

    rows: dict[str, list[str]] = {}
    for p in probes.PROBES:
        heading = next(h for prefix, h in CATEGORIES if p.id.startswith(prefix))
        tmp = Path(tempfile.mkdtemp(prefix="digail-probe-"))
        try:
            got = probes.outcome(p, tmp)
        finally:
            shutil.rmtree(tmp, ignore_errors=True)
        if got is None:
            text = "accepted"
        else:
            text = got.replace(str(tmp) + "/", "").replace(str(tmp), ".")
            text = re.sub(r"; allowed: vae\.\* and train\.\*.*", "; allowed: vae.\\*, train.\\* and a short list of "
                          "stage settings", text)
            text = "refused: " + (text if len(text) <= 170 else text[:167].rstrip() + "…").replace("|", "\\|")
        rows.setdefault(heading, []).append(f"| {p.what.replace('|', chr(92) + '|')} | {text} |")
    parts = [f"### {heading}\n\n| tried | what it gets |\n| --- | --- |\n" + "\n".join(lines)
             for heading, lines in rows.items()]
    return "\n\n".join(parts)


def main() -> int:
    page = PAGE.read_text()
    start, end = page.index(START) + len(START), page.index(END)
    PAGE.write_text(page[:start] + "\n" + table() + "\n\n" + page[end:])
    print(f"wrote {PAGE}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
