"""The command line's flag tables: renamed flags refused with their new names, the settings `--help` leaves out
(still flags, recorded in the run), and the benchmark variants' flags read by `digail train`'s own parser."""

from __future__ import annotations

import dataclasses
import json
import os
import re
import subprocess
import sys
import typing
from pathlib import Path

import pytest
import tyro

from digail.cli import main
from digail.commands.flags import RENAMED_FLAGS, STUDY_SETTINGS, flag_of, renamed
from digail.commands.train import TrainArgs, resume_args

ROOT = Path(__file__).resolve().parents[1]
ENV = "digail/CircleWorld-v0"
MAX_TRAIN_FLAGS = 60
"""what `digail train --help` may list at most: a newcomer reads it through"""


def _help(argv: list[str]) -> list[str]:
    """The flags a help screen lists, counted as a user does: `COLUMNS=200 digail ... --help | grep -oE "│ +--..."`
    (in a subprocess: tyro draws its boxes only for a real output stream)."""
    env = {**os.environ, "COLUMNS": "200", "OMP_NUM_THREADS": "1"}
    proc = subprocess.run([sys.executable, "-m", "digail.cli", *argv], capture_output=True, text=True, env=env,
                          timeout=300)
    assert proc.returncode == 0, proc.stderr
    return [m.split()[-1] for m in re.findall(r"│ +--[a-z0-9.-]+", proc.stdout)]


def test_train_help_lists_at_most_60_flags_and_help_all_every_one():
    shown = _help(["train", "--help"])
    assert 20 <= len(shown) <= MAX_TRAIN_FLAGS, shown
    every = _help(["train", "--help-all"])
    hidden = {flag_of(path) for path in STUDY_SETTINGS["train"]}
    assert hidden <= set(every) and not hidden & set(shown)
    assert set(shown) <= set(every)
    # flags named before --help (a hidden one with its value among them) still show the help
    assert _help(["train", "--train.ppo.clip", "0.3", "--train.shuffle-codes", "--help"]) == shown


def test_help_all_is_help_for_a_command_that_hides_nothing():
    assert _help(["pretrain", "--help-all"]) == _help(["pretrain", "--help"])


def test_study_settings_name_fields_of_the_command():
    """Every row names a field of `digail train`'s arguments, so a renamed or moved field cannot leave a stale row."""
    for path in STUDY_SETTINGS["train"]:
        cls: typing.Any = TrainArgs
        for part in path.split("."):
            hints = typing.get_type_hints(cls)
            assert part in {f.name for f in dataclasses.fields(cls)}, path
            cls = hints[part]


@pytest.mark.parametrize("old", sorted(RENAMED_FLAGS))
def test_a_renamed_flag_is_refused_naming_the_new_one(old, capsys):
    new = RENAMED_FLAGS[old]
    for argv in (["train", old, "1"], ["pretrain", f"{old}=1"], ["train", old.replace("-", "_").replace("__", "--")]):
        assert main(argv) == 2
        err = capsys.readouterr().err.strip()
        assert len(err.splitlines()) == 1 and new in err and "Traceback" not in err, err


def test_renamed_reads_old_spellings():
    assert renamed("--bc-weight") == "--train.bc-weight"
    assert renamed("--bc_weight") == "--train.bc-weight"
    assert renamed("--train.bc-weight") is None
    # a boolean's no- form points at the new no- form
    assert renamed("--vae.no-codes") == "--no-codes" and renamed("--no-bc-weight") == "--train.no-bc-weight"
    # no old name is still a flag of a command: each is refused everywhere
    every = set(tyro_flags(TrainArgs))
    assert not set(RENAMED_FLAGS) & every


def tyro_flags(cls: type) -> list[str]:
    """Every flag tyro makes of `cls` (from its full help)."""
    import contextlib
    import io

    out = io.StringIO()
    with contextlib.redirect_stdout(out), pytest.raises(SystemExit):
        tyro.cli(cls, args=["--help"])
    return re.findall(r"(--[a-z0-9.-]+)", out.getvalue())


@pytest.fixture(scope="module")
def demos(tmp_path_factory):
    path = tmp_path_factory.mktemp("flags") / "demos"
    assert main(["demos", ENV, "--episodes", "6", "--out", str(path)]) == 0
    return path


def test_a_hidden_switch_is_set_and_recorded(demos, tmp_path):
    """A switch `--help` leaves out is a flag like any other: it reaches the trainer and the run's config.json."""
    run = tmp_path / "run"
    assert main(["train", "--method", "gail", "--demos", str(demos), "--preset", "smoke", "--train.shuffle-codes",
                 "--train.ppo.clip", "0.3", "--out", str(run)]) == 0
    config = json.loads((run / "config.json").read_text())
    assert config["train"]["shuffle_codes"] is True and config["train"]["ppo"]["clip"] == 0.3
    assert resume_args(run).train.shuffle_codes is True


def test_a_run_folder_recording_the_old_bc_weight_resumes_with_it(demos, tmp_path):
    """Runs made before --bc-weight became --train.bc-weight record it among the arguments; it still counts."""
    run = tmp_path / "old"
    assert main(["train", "--method", "gail", "--demos", str(demos), "--preset", "smoke", "--out", str(run)]) == 0
    config = json.loads((run / "config.json").read_text())
    config["args"]["bc_weight"] = 2.5
    (run / "config.json").write_text(json.dumps(config))
    assert resume_args(run).train.bc_weight == 2.5


VARIANTS = sorted((ROOT / "benchmarks" / "variants").glob("*/*.variant"))


def _variant_flags(path: Path) -> list[str]:
    lines = [ln.split() for ln in path.read_text().splitlines()]
    directives = {"pretrain", "vae", "budget", "continue"}
    assert all(not w or w[0].startswith(("#", "--")) or w[0] in directives for w in lines), path
    return [word for w in lines if w and w[0].startswith("--") for word in w]


def test_every_published_method_has_a_variant():
    names = {p.stem for p in VARIANTS}  # fetch_fewdemo.py names the landmark route's methods too
    scripts = ("fetch_reward_table.py", "fetch_fewdemo.py", "studies/fetch_rewards.py", "studies/fetch_rot_screen.py")
    for script in scripts:
        text = (ROOT / "benchmarks" / script).read_text()
        for method in re.findall(r'"((?:digail|flatbc|gail)-l2[a-z0-9-]*)"', text):
            assert method in names, (script, method)


@pytest.mark.parametrize("path", VARIANTS, ids=lambda p: f"{p.parent.name}/{p.stem}")
def test_a_variant_is_digail_train_flags(path):
    flags = _variant_flags(path)
    assert not [f for f in flags if renamed(f.partition("=")[0])], path
    tyro.cli(TrainArgs, args=flags)  # digail train's own parser: a flag it does not know fails here


def test_the_reference_lists_both_tables():
    text = (ROOT / "docs" / "reference" / "config.md").read_text()
    hidden_part = text.split("## What `--help` leaves out")[1].split("\n## ")[0]
    rows = [line.split("|")[1] for line in hidden_part.splitlines() if line.startswith("| `")]
    listed = {flag for row in rows for flag in re.findall(r"`(--[a-z0-9.-]+)`", row)}
    assert listed == {flag_of(path) for path in STUDY_SETTINGS["train"]}
    renamed_part = text.split("## Renamed flags")[1].split("\n## ")[0]
    rows = dict(re.findall(r"\| `(--[a-z0-9._-]+)` \| `(--[a-z0-9._-]+)` \|", renamed_part))
    assert rows == RENAMED_FLAGS


def _help_text(argv: list[str], monkeypatch, capsys) -> str:
    monkeypatch.setenv("COLUMNS", "200")
    try:
        main(argv)
    except SystemExit as stop:
        assert stop.code == 0
    return capsys.readouterr().out


@pytest.mark.parametrize("command", ["generate", "pretrain", "train", "import", "run", "sweep"])
def test_help_says_each_default_once(command, monkeypatch, capsys):
    """A flag whose docstring names its default ("(default: the dataset's env)") gets no "(default: None)" after it."""
    text = " ".join(_help_text([command, "--help"], monkeypatch, capsys).split())
    assert "(default:" in text
    twice = re.search(r"\(default: (?:[^()]|\([^()]*\))*\) \(default: ", text)
    assert twice is None, twice.group(0) if twice else ""


def test_help_reads_a_docstring_as_one_paragraph(monkeypatch, capsys):
    """The source's line breaks inside a flag's docstring are not printed: at 200 columns `--vae`'s help, two
    source lines, fits its first row."""
    rows = _help_text(["generate", "--help"], monkeypatch, capsys).splitlines()
    row = next(r for r in rows if r.lstrip(" │").startswith("--vae "))
    assert "covers the sources, else the run's model segments them causally" in row, row
