"""Write a probe table of docs/reference/errors.md from the probes of a failure-paths test module: each probe is run
in a temporary folder, and what it gets (accepted, or its refusal sentence) goes into the table.

    python scripts/probe_table.py             # the fourth round (tests/test_failure_paths_round4.py), "## Probes"
    python scripts/probe_table.py --round 5   # the fifth (tests/test_failure_paths_round5.py), "## Probes, fifth round"
    python scripts/probe_table.py --round 5-code   # its code side (tests/test_failure_paths_round5_code.py)
    python scripts/probe_table.py --round 6   # the sixth (tests/test_failure_paths_round6.py), "## Probes, sixth round"

Each round's table goes between its section's opening paragraph (ending in the round's `START` sentence) and the
next section or the API reference. A test in each module (`test_the_reliability_page_lists_every_probe`) checks
that every probe has its row. Sentences are cut at about 170 characters and the temporary folder's path is taken
out of them, so the table reads the same on any machine (memory sizes aside).
"""

from __future__ import annotations

import argparse
import importlib.util
import re
import shutil
import sys
import tempfile
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parents[1]
PAGE = ROOT / "docs" / "reference" / "errors.md"
CATEGORIES = {
    "4": [("set-", "Sweep overrides (`--set`)"), ("spec-", "Sweep spec files"), ("force-", "`--force`"),
        ("import-", "Imported files"), ("subset-", "Demonstration subsets"), ("cli-", "Demonstration subsets"),
        ("replay-", "Replay buffers in checkpoints"), ("utf8-", "Paths that are not UTF-8"),
        ("lock-", "Lock files"), ("compose-cli", "Analysis commands on a run folder"),
        ("evaluate-", "Analysis commands on a run folder"), ("segment-", "Analysis commands on a run folder"),
        ("report-", "Analysis commands on a run folder"), ("compose-", "Composition schedules"),
        ("resume-", "Resume paths")],
    "5": [("export-", "Segmentation exports (`digail segment --export`)"),
        ("keys-", "Observation keys (`digail segment`)"), ("read-rm-", "robomimic files"),
        ("read-lr-", "LeRobot datasets"), ("read-im-", "imitation datasets folders"),
        ("import-", "Import outputs (`digail import --out`)")],
    "6": [("mw-", "Meta-World env ids and commands"), ("preset-", "Presets"),
          ("mwds-", "Meta-World datasets"), ("reward-", "Imitation-reward settings (`--train.imitation.*`)"),
          ("rs-", "robosuite-made robomimic files"), ("again-", "The fifth round's classes again")],
    "5-code": [("data-", "Code named by a dataset or a run folder"), ("sweep-", "Sweep values of `train.disc_obs`"),
               ("view-", "D's views of your own (`--train.disc-obs module:function`)"), ("msg-", "Messages")],
}
"""per round: probe id prefix -> the table's heading, in the page's order"""
START = {"4": "the paths are relative to the probe's folder.\n",
         "5": "the paths are relative to the probe's folder (a fresh copy of the run and its data).\n",
         "5-code": "the planted modules check that they never ran.\n",
         "6": "a probe's folder keeps no output it was refused.\n"}
"""the sentence that ends each round's opening paragraph"""
END = "::: digail.errors"


def _load(round_: str) -> Any:
    # the probes are a test module; it is loaded from its file rather than by putting tests/ on the import path
    name = f"test_failure_paths_round{round_.replace('-', '_')}"
    if name in sys.modules:
        return sys.modules[name]
    if round_ != "4":  # the later rounds reuse the fourth's helpers (the sixth the fifth's too), imported by name
        _load("4")
    if round_ == "6":
        _load("5-code")
    spec = importlib.util.spec_from_file_location(name, ROOT / "tests" / f"{name}.py")
    assert spec is not None and spec.loader is not None
    probes = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = probes  # its dataclasses look their module up by name
    spec.loader.exec_module(probes)
    return probes


def table(round_: str = "4") -> str:
    probes = _load(round_)
    base = None
    if round_ == "5":  # the run folder and data every probe works on a copy of, made once
        base = probes.make_base(Path(tempfile.mkdtemp(prefix="digail-probe-base-")))
    rows: dict[str, list[str]] = {}
    try:
        for p in probes.PROBES:
            heading = next(h for prefix, h in CATEGORIES[round_] if p.id.startswith(prefix))
            tmp = Path(tempfile.mkdtemp(prefix="digail-probe-"))
            try:
                got = probes.outcome(p, tmp) if base is None else probes.outcome(p, tmp, base)
            finally:
                shutil.rmtree(tmp, ignore_errors=True)
            if got is None:
                text = "accepted"
            else:
                text = got.replace(str(tmp) + "/", "").replace(str(tmp), ".")
                text = re.sub(r"; allowed: vae\.\* and train\.\*.*", "; allowed: vae.\\*, train.\\* and a short list "
                              "of stage settings", text)
                text = "refused: " + (text if len(text) <= 170 else text[:167].rstrip() + "…").replace("|", "\\|")
                text = text.replace("[", "\\[").replace("]", "\\]")  # a sentence's brackets are no Markdown link
            rows.setdefault(heading, []).append(f"| {p.what.replace('|', chr(92) + '|')} | {text} |")
    finally:
        if base is not None:
            shutil.rmtree(base, ignore_errors=True)
    parts = [f"### {heading}\n\n| tried | what it gets |\n| --- | --- |\n" + "\n".join(lines)
             for heading, lines in rows.items()]
    return "\n\n".join(parts)


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--round", choices=sorted(START), default="4", dest="round_")
    args = parser.parse_args()
    page = PAGE.read_text()
    start = page.index(START[args.round_]) + len(START[args.round_])
    following = [i for i in (page.find("\n## ", start), page.find(END, start)) if i >= 0]
    end = min(following) + (1 if page[min(following)] == "\n" else 0)
    PAGE.write_text(page[:start] + "\n" + table(args.round_) + "\n\n" + page[end:])
    print(f"wrote {PAGE}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
