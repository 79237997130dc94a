"""The harness every failure-path probe module shares (tests/test_probes_*.py): the probe, the table that collects
them, the one way a command line is run, and the checks each probe's answer gets.

A probe is what a user might try and what digail must give back: accepted, or refused with one sentence holding the
expected phrase (exit status 2 from the CLI, no traceback). A refused probe changes nothing in its folder (what its
`setup` made there is recorded first) and leaves no output behind. Each module's probes, with what each gets, are a
section of the reliability page (docs/reference/errors.md), written by `python scripts/probe_table.py`.
"""

from __future__ import annotations

import contextlib
import io
import os
import sys
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import digail.user_envs
from digail.cli import main
from digail.errors import UserError

ROOT = Path(__file__).resolve().parents[1]
PAGE = ROOT / "docs" / "reference" / "errors.md"
CW = "digail/CircleWorld-v0"
CW_DEMOS = "digail/circleworld/expert-v0"
MW = "metaworld/pick-place-v3"
MW_DEMOS = "digail/metaworld-pick-place/expert-v0"
RUN = ROOT / "benchmarks" / "results" / "runs" / "pendulum_vae_s2"
"""a committed run folder (a Pendulum VAE)"""
METAWORLD_PROBES = ("mw-", "mwds-", "preset-", "again-")
"""the ids of probes on Meta-World envs and datasets: skipped where Meta-World is not installed"""
USERS_CODE = ("view-", "sweep-")
"""the ids of probes whose planted module is named by the user (a view, a sweep's env), so it runs"""
OUTPUTS = ("out", "run-new", "vae")
"""the names the probes give their outputs: none may appear when a probe is refused"""


@dataclass(frozen=True)
class Probe:
    id: str
    """a short name"""
    what: str
    """what was tried, in the docs' words"""
    run: Callable[[Path], object]
    """runs the probe in its own folder; raises UserError when refused"""
    expect: str | None
    """a phrase of the refusal, or None: accepted"""
    setup: Callable[[Path], object] | None = None
    """makes what the probe tries on in its folder, before the folder's contents are recorded"""
    on_base: bool = False
    """the probe's folder starts as a copy of its module's base folder (a run and the data it was made from)"""


class ProbeTable(list[Probe]):
    """A module's probes, in the order the reliability page lists them."""

    def add(self, pid: str, what: str, expect: str | None, setup: Callable[[Path], object] | None = None,
            on_base: bool = False) -> Callable[[Callable[[Path], object]], Callable[[Path], object]]:
        """Decorator: the function is the probe `pid`'s run."""
        def add(fn: Callable[[Path], object]) -> Callable[[Path], object]:
            assert all(p.id != pid for p in self), f"two probes are named {pid}"
            self.append(Probe(pid, what, fn, expect, setup, on_base))
            return fn

        return add


def cli(tmp: Path, *argv: str) -> None:
    """Run `digail argv` in `tmp`; a refusal becomes the UserError of its one line.

    Lines a shell shows beside the sentence are not part of it: deprecation warnings of old flag names, progress
    bars and `note:` lines."""
    err = io.StringIO()
    old = Path.cwd()
    os.chdir(tmp)
    try:
        with contextlib.redirect_stderr(err), contextlib.redirect_stdout(io.StringIO()):
            code = main(list(argv))
    finally:
        os.chdir(old)
    text = err.getvalue()
    assert "Traceback" not in text, text
    if code == 0:
        return
    lines = [ln for ln in text.splitlines() if ln.strip() and "is deprecated; use" not in ln and "%|" not in ln
             and not ln.startswith("note: ")]
    assert code == 2 and len(lines) == 1 and ": error: " in lines[0], (code, text)
    raise UserError(lines[0].split(": error: ", 1)[1])


def tree(path: Path, stamps: bool = True) -> dict[str, bytes | str]:
    """Everything below `path`: file contents, link targets, folders and other kinds of file. With `stamps`, a file
    rewritten with the same bytes counts as changed too (its inode or modification time moved): a refusal must come
    before any write, not after a write that happened to give the same bytes."""
    out: dict[str, bytes | str] = {}
    for p in sorted(path.rglob("*")):
        key = str(p.relative_to(path))
        if p.is_symlink():
            out[key] = "-> " + os.readlink(p)
        elif p.is_file():
            st = p.stat()
            out[key] = p.read_bytes() + (f"\0inode {st.st_ino} mtime {st.st_mtime_ns}".encode() if stamps else b"")
        elif p.is_dir():
            out[key] = "dir"
        else:
            out[key] = "special"
    return out


def outcome(p: Probe, tmp: Path) -> str | None:
    """The probe's sentence when refused, None when accepted. It starts with no module named by the user and
    leaves the import path as it was (some probes plant modules)."""
    state = (set(digail.user_envs._NAMED), dict(digail.user_envs._UNNAMED), list(sys.path))
    digail.user_envs._NAMED.clear()
    digail.user_envs._UNNAMED.clear()
    try:
        p.run(tmp)
    except UserError as exc:
        return " ".join(str(exc).split())
    finally:
        digail.user_envs._NAMED.clear()
        digail.user_envs._NAMED.update(state[0])
        digail.user_envs._UNNAMED.clear()
        digail.user_envs._UNNAMED.update(state[1])
        sys.path[:] = state[2]
    return None


def prepare(p: Probe, tmp: Path, base: Path | None = None) -> None:
    """The probe's folder before it runs: a copy of `base` (for `on_base` probes), then what `setup` makes."""
    if p.on_base:
        assert base is not None, f"{p.id} needs its module's base folder"
        copy_base(base, tmp)
    if p.setup is not None:
        p.setup(tmp)


def check_probe(p: Probe, tmp: Path, base: Path | None = None) -> None:
    """Prepare, run and judge probe `p` in `tmp`: the answer it must get; when refused, one line, the folder as
    `setup` left it (when there is one), no output, no temporary folder; a module planted where only data names it
    never ran."""
    import pytest

    if p.id.startswith(METAWORLD_PROBES):
        pytest.importorskip("metaworld")
    prepare(p, tmp, base)
    before = tree(tmp) if p.setup is not None or p.on_base else None
    sentence = outcome(p, tmp)
    if not p.id.startswith(USERS_CODE):
        assert ran(tmp) == [], f"{p.id} ran a module that data named"
    if p.expect is None:
        assert sentence is None, f"{p.id} was refused: {sentence}"
        return
    assert sentence is not None, f"{p.id} was accepted"
    assert p.expect in sentence, sentence
    assert "\n" not in sentence and "Traceback" not in sentence
    if before is not None:
        after = tree(tmp)
        changed = sorted(k for k in set(before) | set(after) if before.get(k) != after.get(k))
        assert not changed, f"{p.id} was refused but changed {changed}"
    left = [name for name in OUTPUTS if (tmp / name).exists() and (before is None or name not in before)]
    assert not left and not list(tmp.glob(".*.tmp-*")), f"{p.id} was refused but wrote {left}"


def copy_base(base: Path, tmp: Path) -> None:
    """A copy of the base folder `base` in `tmp`, its records of absolute paths pointed at the copy."""
    import shutil

    for child in base.iterdir():
        target = tmp / child.name
        if child.is_dir():
            shutil.copytree(child, target, symlinks=True)
        else:
            shutil.copy2(child, target)
    for record in (tmp / "demos" / "data" / "metadata.json", tmp / "vae" / "config.json"):
        if record.is_file():
            record.write_text(record.read_text().replace(str(base), str(tmp)))


def page_section(heading: str) -> str:
    """The reliability page's section `## heading`, up to the next section."""
    page = PAGE.read_text()
    assert f"\n## {heading}\n" in page, f"docs/reference/errors.md has no section '## {heading}'"
    return page.split(f"\n## {heading}\n", 1)[1].split("\n## ", 1)[0].split("::: digail.errors", 1)[0]


def assert_published(probes: list[Probe], heading: str) -> None:
    """docs/reference/errors.md lists `probes` in its section `heading`: one row each, under the same words."""
    section = page_section(heading)
    rows = [ln for ln in section.splitlines() if ln.startswith("| ") and not ln.startswith(("| tried", "| ---"))]
    missing = [p.id for p in probes if f"| {p.what.replace('|', chr(92) + '|')} |" not in section]
    assert not missing, f"probes without a row in the reliability page: {missing}"
    assert len(rows) == len(probes), f"the section '{heading}' has {len(rows)} rows for {len(probes)} probes"


def plant(folder: Path, name: str, body: str = "") -> Path:
    """A module `name`.py in `folder` that leaves `name`.ran beside itself when imported, then runs `body`."""
    folder.mkdir(parents=True, exist_ok=True)
    marker = folder / f"{name}.ran"
    (folder / f"{name}.py").write_text(f"open({str(marker)!r}, 'w').close()\n{body}")
    return marker


def ran(tmp: Path) -> list[str]:
    """The planted modules that ran."""
    return sorted(p.name for p in tmp.rglob("*.ran"))


def sweep_check(sets: tuple[str, ...] = (), spec: str | None = None, tmp: Path | None = None) -> None:
    """What `digail sweep` checks before Ray starts or a file is written."""
    from digail.commands.sweep import check_spec
    from digail.sweep.plan import plan
    from digail.sweep.spec import build_spec

    spec_file = None
    if spec is not None:
        assert tmp is not None
        spec_file = tmp / "spec.toml"
        spec_file.write_text(spec)
    built = build_spec(envs=None if spec else (CW,), methods=None if spec else ("vae", "digail"), sets=sets,
                       spec_file=spec_file, preset="smoke")
    check_spec(built, plan(built))


def refusal(argv: list[str], *phrases: str, cwd: Path | None = None) -> str:
    """The one sentence `digail argv` (run in `cwd`, by default the current folder) is refused with, checked to
    hold each of `phrases`."""
    try:
        cli(Path.cwd() if cwd is None else cwd, *argv)
    except UserError as exc:
        sentence = str(exc)
    else:
        raise AssertionError(f"`digail {' '.join(argv)}` was accepted")
    for phrase in phrases:
        assert phrase in sentence, sentence
    return sentence


def mw_train(tmp: Path, *flags: str, demos: str = MW_DEMOS, method: str = "gail") -> None:
    """`digail train` on the shipped Meta-World pick-place demonstrations, one smoke iteration."""
    cli(tmp, "train", "--method", method, "--demos", demos, "--preset", "smoke", "--train.iterations", "1", *flags,
        "--out", "run-new")


def cw_train(tmp: Path, *flags: str) -> None:
    """`digail train` GAIL on Circle-World, one smoke iteration (the reward settings' probes)."""
    cli(tmp, "train", "--method", "gail", "--demos", CW_DEMOS, "--preset", "smoke", "--train.iterations", "1",
        *flags, "--out", "run-new")


def good_npz(path: Path) -> Path:
    """A small valid `.npz` of demonstrations (two episodes of 10 steps, 3-d observations, 1-d actions)."""
    import numpy as np

    rng = np.random.default_rng(0)
    np.savez(path, observations=rng.normal(size=(20, 3)).astype(np.float32),
             actions=rng.normal(size=(20, 1)).astype(np.float32), episode_ends=np.array([10, 20]))
    return path


def users_folder(path: Path) -> Path:
    """A folder of the user's at `path`: files digail must never delete."""
    (path / "notes").mkdir(parents=True)
    (path / "thesis.tex").write_text("a user's file\n")
    (path / "notes" / "todo.txt").write_text("more of them\n")
    return path
