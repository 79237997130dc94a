"""Write the probe tables of docs/reference/errors.md from the failure-path probes (tests/test_probes_*.py): each
probe is run in a temporary folder, as its test runs it, and what it gets (accepted, or its refusal sentence) goes
into its section's table.

    python scripts/probe_table.py                 # every section
    python scripts/probe_table.py --surface cli   # one: cli, datasets, exports, sweeps or code

Each module's tables go between its section's opening paragraph (`## Probes: ...`, ending in a blank line after
its first paragraph) and the next section. A test in each module (`test_the_reliability_page_lists_every_probe`)
checks that every probe has its row. Sentences are cut at about 170 characters and the temporary folder's path is
taken out of them, so the table reads the same on any machine (memory sizes aside).
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
SURFACES: dict[str, tuple[str, list[tuple[str, str]]]] = {
    "cli": ("Probes: command-line arguments and output paths", [
        ("force-", "`--force`"), ("subset-", "Demonstration subsets"), ("cli-", "Demonstration subsets"),
        ("utf8-", "Paths that are not UTF-8"), ("lock-", "Lock files"),
        *[(p, "Report pages (`digail report --out`)") for p in ("report-out", "report-compare", "report-own",
                                                               "report-again", "report-device")],
        ("out-", "Run and dataset folders (`--out` of `pretrain`, `train`, `run`, `demos`, `generate`)"),
        ("compose-cli", "Analysis commands on a run folder"), ("evaluate-", "Analysis commands on a run folder"),
        ("segment-", "Analysis commands on a run folder"), ("report-", "Analysis commands on a run folder"),
        ("compose-", "Composition schedules"), ("resume-", "Resume paths"),
        ("mw-", "Meta-World env ids and commands"), ("preset-", "Presets"),
        ("reward-", "Imitation-reward settings (`--train.imitation.*`)"),
        ("size-", "Sizes and ranges"), ("range-", "Sizes and ranges")]),
    "datasets": ("Probes: datasets and imports", [
        ("import-into-source", "Import outputs (`digail import --out`)"),
        ("import-over-folder", "Import outputs (`digail import --out`)"), ("import-", "Imported files"),
        ("replay-", "Replay buffers in checkpoints"), ("keys-", "Observation keys (`digail segment`)"),
        ("read-rm-", "robomimic files"), ("read-lr-", "LeRobot datasets"), ("read-im-", "imitation datasets folders"),
        ("mwds-", "Meta-World datasets"), ("rs-", "robosuite-made robomimic files")]),
    "exports": ("Probes: exports", [
        ("export-names-clash", "Refusals the source gives, before the run folder is touched"),
        ("export-lerobot-has-column", "Refusals the source gives, before the run folder is touched"),
        ("export-robomimic-reexport", "Refusals the source gives, before the run folder is touched"),
        ("export-lerobot-frame-gap", "Refusals the source gives, before the run folder is touched"),
        ("export-", "Where an export may go (`digail segment --export`)"),
        ("rs-export-", "Exports of robosuite-made robomimic files")]),
    "sweeps": ("Probes: sweeps", [
        ("set-", "Sweep overrides (`--set`)"), ("spec-", "Sweep spec files"),
        ("reward-set-", "Imitation-reward settings in a sweep"), ("options-", "The sweep's own options and folder")]),
    "code": ("Probes: code named by data", [
        ("data-", "Code named by a dataset or a run folder"), ("sweep-", "Sweep values of `train.disc_obs`"),
        ("view-", "D's views of your own (`--train.disc-obs module:function`)"), ("msg-", "Messages"),
        ("again-", "The same classes on Meta-World")]),
}
"""per module (tests/test_probes_<name>.py): its section of the page, and probe id prefix -> the table's heading,
in the page's order (the first prefix that fits)"""


def _load(name: str) -> Any:
    # the probes are a test module, loaded from its file; the harness modules it imports by name come first
    for helper in ("probe_kit", "probe_data"):
        if helper not in sys.modules:
            _load_file(helper)
    return _load_file(f"test_probes_{name}")


def _load_file(module: str) -> Any:
    spec = importlib.util.spec_from_file_location(module, ROOT / "tests" / f"{module}.py")
    assert spec is not None and spec.loader is not None
    probes = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = probes  # its dataclasses look their module up by name
    spec.loader.exec_module(probes)
    return probes


def table(name: str) -> str:
    probes = _load(name)
    probe_kit = sys.modules["probe_kit"]
    base = None
    if any(p.on_base for p in probes.PROBES):  # the run folder and data such probes work on a copy of, made once
        base = probes.make_base(Path(tempfile.mkdtemp(prefix="digail-probe-base-")))
    rows: dict[str, list[str]] = {}
    order = list(dict.fromkeys(h for _, h in SURFACES[name][1]))
    try:
        for p in probes.PROBES:
            heading = next(h for prefix, h in SURFACES[name][1] if p.id.startswith(prefix))
            tmp = Path(tempfile.mkdtemp(prefix="digail-probe-"))
            try:
                probe_kit.prepare(p, tmp, base)
                got = probe_kit.outcome(p, tmp)
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
    parts = [f"### {heading}\n\n| tried | what it gets |\n| --- | --- |\n" + "\n".join(rows[heading])
             for heading in order if heading in rows]
    return "\n\n".join(parts)


def write(name: str) -> None:
    """Replace the tables of `name`'s section: everything after its opening paragraph, up to the next section."""
    heading = f"\n## {SURFACES[name][0]}\n"
    page = PAGE.read_text()
    start = page.index("\n\n", page.index(heading) + len(heading)) + 2  # past its opening paragraph
    following = [i for i in (page.find("\n## ", start), page.find("::: digail.errors", start)) if i >= 0]
    end = min(following) + (1 if page[min(following)] == "\n" else 0)
    PAGE.write_text(page[:start] + table(name) + "\n\n" + page[end:])


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--surface", choices=sorted(SURFACES), default=None)
    args = parser.parse_args()
    for name in [args.surface] if args.surface else list(SURFACES):
        write(name)
        print(f"wrote the section '{SURFACES[name][0]}' of {PAGE}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
