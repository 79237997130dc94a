"""Failure-path probes of the command line: arguments and the paths a command is told to write.

`--force` and what it may replace, demonstration subsets, paths that are not UTF-8 and lock files, the analysis
commands on a run folder, composition schedules, resume paths, environment ids and presets, the imitation-reward
settings and the numbers that size memory and time, and `digail report --out`. The probes, with what each gets, are
the reliability page's section of the same name (docs/reference/errors.md).
"""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from probe_kit import (
    CW,
    CW_DEMOS,
    MW,
    MW_DEMOS,
    ROOT,
    RUN,
    Probe,
    ProbeTable,
    assert_published,
    check_probe,
    cli,
    cw_train,
    good_npz,
    mw_train,
    refusal,
    tree,
    users_folder,
)

from digail.cli import main
from digail.errors import UserError
from digail.fsio import MARKER, check_replaceable, digail_made, run_dir_lock

PROBES = ProbeTable()
probe = PROBES.add


# ------------------------------------------------------------------------------------------------ --force
def force(target: str) -> Callable[[Path], None]:
    def run(tmp: Path) -> None:
        from digail.fsio import check_new_dir

        here = tmp / "a" / "inner"
        old = Path.cwd()
        os.chdir(here)
        try:
            check_new_dir(Path(target.replace("TMP", str(tmp))), force=True)
        finally:
            os.chdir(old)

    return run


def _setup_force(tmp: Path) -> None:
    """What the `--force` probes aim at, and a/inner, the current directory they run in."""
    (tmp / "a" / "inner").mkdir(parents=True)
    (tmp / "mine").mkdir()
    (tmp / "mine" / "thesis.tex").write_text("a user's file\n")
    (tmp / "file").write_text("a user's file\n")
    (tmp / "link").symlink_to(tmp / "mine")
    (tmp / "dangling").symlink_to(tmp / "nowhere")
    (tmp / "loop").symlink_to(tmp / "loop")
    (tmp / "empty").mkdir()
    (tmp / "locked-empty").mkdir()
    (tmp / "locked-empty" / ".digail.lock").write_text("")
    (tmp / "marked").mkdir()
    (tmp / "marked" / ".digail").write_text("\n")
    (tmp / "marked" / "extra.txt").write_text("added later\n")
    (tmp / "marker-dir").mkdir()
    (tmp / "marker-dir" / ".digail").mkdir()
    (tmp / "marker-dir" / "thesis.tex").write_text("x\n")
    (tmp / "marked-link").symlink_to(tmp / "marked")
    (tmp / "oldrun").mkdir()
    (tmp / "oldrun" / "config.json").write_text(json.dumps({"env_id": CW, "seed": 0, "kind": "vae"}))
    (tmp / "oldrun" / "model.pt").write_bytes(b"x")
    (tmp / "otherconfig").mkdir()
    (tmp / "otherconfig" / "config.json").write_text(json.dumps({"lr": 0.1}))
    (tmp / "listconfig").mkdir()
    (tmp / "listconfig" / "config.json").write_text("[1]")
    for name, record in (("olddata", {"dataset_id": "x/y-v0", "digail": {}}), ("minari", {"dataset_id": "x/y-v0"})):
        (tmp / name / "data").mkdir(parents=True)
        (tmp / name / "data" / "metadata.json").write_text(json.dumps(record))
        (tmp / name / "data" / "main_data.hdf5").write_bytes(b"x")
    (tmp / "oldsweep" / "trials").mkdir(parents=True)
    (tmp / "oldsweep" / "sweep.json").write_text("{}")


for _pid, _target, _what, _expect in [
    ("force-users-folder", "TMP/mine", "a folder of the user's", "is not a folder digail made"),
    ("force-file", "TMP/file", "a file", "is a file, and --force replaces only a folder"),
    ("force-link-to-users", "TMP/link", "a link to a folder of the user's", "is not a folder digail made"),
    ("force-dangling-link", "TMP/dangling", "a link to nothing", "is a link to nothing"),
    ("force-link-loop", "TMP/loop", "a link to itself", "leads nowhere"),
    ("force-cwd", ".", "`.`, the current directory (even one digail made)", "the current directory"),
    ("force-parent", "..", "`..`", "a folder holding the current directory"),
    ("force-grandparent", "../..", "`../..`", "a folder holding the current directory"),
    ("force-cwd-absolute", "TMP/a/inner", "the current directory by its absolute path", "the current directory"),
    ("force-root", "/", "`/`", "--force would delete /, a filesystem root"),
    ("force-marker-folder", "TMP/marker-dir", "a folder whose `.digail` is a folder", "is not a folder digail made"),
    ("force-other-config", "TMP/otherconfig", "a folder whose config.json is another tool's",
     "is not a folder digail made"),
    ("force-list-config", "TMP/listconfig", "a folder whose config.json is a JSON list", "is not a folder digail made"),
    ("force-minari-not-digail", "TMP/minari", "a Minari dataset digail did not write", "is not a folder digail made"),
    ("force-empty", "TMP/empty", "an empty folder", None),
    ("force-lock-only", "TMP/locked-empty", "a folder holding only a stale lock file", None),
    ("force-marked", "TMP/marked", "a folder with the `.digail` marker", None),
    ("force-marked-link", "TMP/marked-link", "a link to a marked folder", None),
    ("force-old-run", "TMP/oldrun", "a run folder from before the marker (config.json with env_id and seed)", None),
    ("force-old-dataset", "TMP/olddata", "a dataset from before the marker (digail's record in its metadata)", None),
    ("force-old-sweep", "TMP/oldsweep", "a sweep folder from before the marker", None),
]:
    probe(_pid, f"`--force` onto {_what}", _expect, setup=_setup_force)(force(_target))


@probe("force-home", "`--force` onto the home folder (marked)", "the home folder")
def _force_home(tmp: Path) -> None:
    from digail.fsio import check_replaceable

    home = tmp / "home"
    home.mkdir()
    (home / ".digail").write_text("\n")
    old = os.environ.get("HOME")
    os.environ["HOME"] = str(home)
    try:
        check_replaceable(home)
    finally:
        if old is None:
            del os.environ["HOME"]
        else:
            os.environ["HOME"] = old


@probe("force-locked", "`--force` onto a marked folder another process is writing", "is being written by another")
def _force_locked(tmp: Path) -> None:
    import fcntl

    from digail.fsio import check_new_dir

    (tmp / "run").mkdir()
    (tmp / "run" / ".digail").write_text("\n")
    fd = os.open(tmp / "run" / ".digail.lock", os.O_RDWR | os.O_CREAT)
    try:
        fcntl.flock(fd, fcntl.LOCK_EX)
        check_new_dir(tmp / "run", force=True)
    finally:
        os.close(fd)


# ------------------------------------------------------------------------------------------------ subsets
def _subset(episodes: int | None, every: int) -> Callable[[Path], None]:
    def run(_: Path) -> None:
        from digail.data.minari_io import load_dataset
        from digail.data.subset import select_demos

        trajs = list(load_dataset(CW_DEMOS).trajs)[:3]
        select_demos(trajs, episodes, every)

    return run


for _pid, _episodes, _every, _expect in [
    ("subset-zero-episodes", 0, 1, "--demos-episodes must be at least 1"),
    ("subset-too-many", 4, 1, "asks for more episodes than the dataset's 3"),
    ("subset-every-zero", None, 0, "--demos-subsample must be at least 1"),
    ("subset-every-longest", None, 120, "at least as long as every demonstration"),
    ("subset-every-huge", None, 10**9, "at least as long as every demonstration"),
    ("subset-every-longest-minus-1", None, 119, None),
    ("subset-one-every-20", 1, 20, None),
]:
    probe(_pid, f"demonstration subset: episodes {_episodes}, every {_every}-th (3 episodes of 120 transitions)",
          _expect)(_subset(_episodes, _every))


@probe("cli-pretrain-subsample", "`digail pretrain --demos-subsample 100000`", "at least as long as every")
def _cli_subsample(tmp: Path) -> None:
    cli(tmp, "pretrain", "--demos", CW_DEMOS, "--preset", "smoke", "--demos-subsample", "100000", "--out", "vae")


@probe("cli-run-episodes", "`digail run --demos-episodes 100000` (nothing left to block the corrected command)",
       "asks for more episodes")
def _cli_run_episodes(tmp: Path) -> None:
    cli(tmp, "run", CW, "--preset", "smoke", "--demos-episodes", "100000", "--out", "run")


# ------------------------------------------------------------------------------------------------ paths and locks
BAD = "r\udcffn"
SHOWN = "r\\xffn"
for _pid, _argv in [
    ("utf8-train-out", ["train", "--method", "gail", "--demos", CW_DEMOS, "--out", BAD]),
    ("utf8-pretrain-demos", ["pretrain", "--demos", BAD]),
    ("utf8-train-vae", ["train", "--demos", CW_DEMOS, "--vae", BAD]),
    ("utf8-sweep-spec", ["sweep", "--spec", BAD + ".toml", "--out", "s"]),
    ("utf8-evaluate-run", ["evaluate", BAD]),
    ("utf8-report", ["report", BAD]),
    ("utf8-import-source", ["import", BAD + ".npz"]),
    ("utf8-run-out", ["run", CW, "--out", BAD]),
]:
    _shown = " ".join(a.replace(BAD, SHOWN) for a in _argv)
    probe(_pid, f"`digail {_shown}` (a name with the byte 0xff)", "is not valid UTF-8")(
        lambda tmp, a=tuple(_argv): cli(tmp, *a))


@probe("utf8-accented", "`digail import` into a UTF-8 name with accents (`données`)", None)
def _utf8_ok(tmp: Path) -> None:
    good_npz(tmp / "d.npz")
    cli(tmp, "import", "d.npz", "--out", "données")


@probe("lock-folder", "a run folder whose `.digail.lock` is a folder", "is a folder, not digail's lock file")
def _lock_folder(tmp: Path) -> None:
    (tmp / "run" / ".digail.lock").mkdir(parents=True)
    cli(tmp, "segment", "run")


@probe("lock-dangling-link", "a run folder whose `.digail.lock` is a link to a file elsewhere (not created)",
       "is a link, not digail's lock file")
def _lock_dangling(tmp: Path) -> None:

    (tmp / "run").mkdir()
    (tmp / "run" / ".digail.lock").symlink_to(tmp / "elsewhere")
    try:
        with run_dir_lock(tmp / "run"):
            pass
    finally:
        assert not (tmp / "elsewhere").exists(), "the lock was written outside the run folder"


@probe("lock-link-to-file", "a run folder whose `.digail.lock` is a link to a user's file", "is a link")
def _lock_link(tmp: Path) -> None:

    (tmp / "run").mkdir()
    (tmp / "notes.txt").write_text("a user's file\n")
    (tmp / "run" / ".digail.lock").symlink_to(tmp / "notes.txt")
    try:
        with run_dir_lock(tmp / "run"):
            pass
    finally:
        assert (tmp / "notes.txt").read_text() == "a user's file\n", "the lock wrote into a user's file"


# ------------------------------------------------------------------------------------------------ schedules
for _pid, _text, _expect in [
    ("compose-ok", "1:60,0:60", None),
    ("compose-spaces", " 1 : 60 , 0:60 ", None),
    ("compose-empty", "", "cannot read the schedule"),
    ("compose-zero-steps", "0:0", "at least 1"),
    ("compose-code-too-big", "9:10", "uses code 9 but the policy has 2 codes"),
    ("compose-trailing-comma", "0:60,", "cannot read the schedule"),
    ("compose-negative", "0:-5", "cannot read the schedule"),
    ("compose-arabic-digits", "٠:١٠", "cannot read the schedule"),
    ("compose-huge", "0:" + "9" * 30, "longer than an episode"),
    ("compose-too-long", "0:100,1:100", "longer than an episode (120 steps at most)"),
]:
    probe(_pid, f"`digail compose --schedule '{_text}'` (K = 2, episodes of 120 steps)", _expect)(
        lambda tmp, t=_text: __import__("digail.eval.composition", fromlist=["x"]).parse_schedule(t, 2, 120))




def _on_run(*argv: str, damage: str | None = None) -> Callable[[Path], None]:
    def run(tmp: Path) -> None:
        import shutil

        shutil.copytree(RUN, tmp / "run")
        if damage is not None:
            data = (tmp / "run" / damage).read_bytes()
            (tmp / "run" / damage).write_bytes(data[: len(data) // 2])
        cli(tmp, *argv)

    return run


for _pid, _argv, _damage, _expect in [
    ("compose-cli-code", ["compose", "run", "--schedule", "9:10", "--episodes", "1"], None,
     "uses code 9 but the policy has"),
    ("compose-cli-episodes", ["compose", "run", "--episodes", "0"], None, "--episodes must be at least 1"),
    ("compose-cli-truncated-model", ["compose", "run", "--schedule", "0:10", "--episodes", "1"], "model.pt",
     "is corrupt, truncated or not a digail file"),
    ("evaluate-cli-episodes", ["evaluate", "run", "--episodes", "0"], None, "--episodes must be at least 1"),
    ("evaluate-cli-seed", ["evaluate", "run", "--seed", "-1"], None, "--seed must be between"),
    ("evaluate-cli-truncated-config", ["evaluate", "run", "--episodes", "1"], "config.json", "is not valid JSON"),
    ("segment-cli-users-demos", ["segment", "run", "--demos", "nowhere/nothing-v0"], None, "nowhere/nothing-v0"),
    ("report-cli-users-folder", ["report", "mine"], None, "mine"),
]:
    def _run_on(tmp: Path, argv: tuple[str, ...] = tuple(_argv), damage: str | None = _damage) -> None:
        (tmp / "mine").mkdir()
        (tmp / "mine" / "thesis.tex").write_text("x\n")
        _on_run(*argv, damage=damage)(tmp)

    probe(_pid, f"`digail {' '.join(_argv)}` on a copy of a committed Pendulum VAE run"
          + (f" with its {_damage} cut in half" if _damage else ""), _expect)(_run_on)


# ------------------------------------------------------------------------------------------------ resume paths
def _config(tmp: Path, data: object) -> None:
    (tmp / "run").mkdir(exist_ok=True)
    (tmp / "run" / "config.json").write_text(json.dumps(data))


for _pid, _what, _setup, _argv, _expect in [
    ("resume-missing", "`digail train --resume` a folder that does not exist", None, ["train", "--resume", "nope"],
     "does not exist"),
    ("resume-vae", "`digail train --resume` a VAE folder", {"kind": "vae", "env_id": CW, "seed": 0},
     ["train", "--resume", "run"], "is a VAE run folder"),
    ("resume-list-config", "`digail train --resume` a folder whose config.json is a list", [1, 2],
     ["train", "--resume", "run"], "does not hold a JSON object"),
    ("resume-no-args", "`digail train --resume` a folder whose config.json records no arguments",
     {"kind": "digail", "env_id": CW, "seed": 0}, ["train", "--resume", "run"], "records no training arguments"),
    ("resume-bad-args", "`digail train --resume` a folder whose recorded arguments are not a training's",
     {"kind": "digail", "args": {"seed": "zero", "nonsense": 1}}, ["train", "--resume", "run"],
     "training arguments in run/config.json are invalid"),
    ("resume-run-on-train", "`digail run --resume` a `digail train` folder",
     {"kind": "digail", "args": {"seed": 0}}, ["run", "--resume", "run"], "is not a folder made by `digail run`"),
    ("resume-run-users", "`digail run --resume` a folder of the user's", "users", ["run", "--resume", "run"],
     "is not a folder made by `digail run`"),
]:
    def _run_resume(tmp: Path, setup: object = _setup, argv: tuple[str, ...] = tuple(_argv)) -> None:
        if setup == "users":
            (tmp / "run").mkdir()
            (tmp / "run" / "thesis.tex").write_text("x\n")
        elif setup is not None:
            _config(tmp, setup)
        cli(tmp, *argv)

    probe(_pid, _what, _expect)(_run_resume)


# ------------------------------------------------------------------------------------------------ Meta-World env ids
def cli_process(tmp: Path, *argv: str) -> None:
    """`digail argv` in a process of its own, stderr as a shell shows it (warnings included, which the test
    harness would otherwise capture): one line on refusal."""
    import os

    env = {**os.environ, "PYTHONPATH": os.pathsep.join(p for p in sys.path if p)}
    done = subprocess.run([sys.executable, "-m", "digail.cli", *argv], cwd=tmp, capture_output=True, text=True,
                          timeout=300, env=env)
    if done.returncode == 0:
        return
    lines = [ln for ln in done.stderr.splitlines() if ln.strip()]
    assert done.returncode == 2 and len(lines) == 1 and ": error: " in lines[0], (done.returncode, done.stderr)
    raise UserError(lines[0].split(": error: ", 1)[1])


probe("mw-id-v2-shell", "`digail demos metaworld/pick-place-v2 --episodes 1` in a shell (Gymnasium's deprecation "
      "warning must not add lines)", "is deprecated")(
    lambda tmp: cli_process(tmp, "demos", "metaworld/pick-place-v2", "--episodes", "1", "--out", "out"))

for _pid, _env, _expect in [
    ("mw-id-unknown-task", "metaworld/no-such-task-v3", "unknown environment id"),
    ("mw-id-v2", "metaworld/pick-place-v2", "is deprecated"),
    ("mw-id-upper", "metaworld/Pick-Place-v3", "unknown environment id"),
    ("mw-id-no-version", "metaworld/pick-place", "names no version; pass 'metaworld/pick-place-v3'"),
    ("mw-id-namespace-only", "metaworld/", "Malformed environment ID"),
    ("mw-id-trailing-space", "metaworld/pick-place-v3 ", "Malformed environment ID"),
    ("mw-id-bare-task", "pick-place-v3", "unknown environment id"),
    ("mw-id-module-form", "metaworld:pick-place-v3", "unknown environment id"),
    ("mw-id-path", "../metaworld/pick-place-v3", "Malformed environment ID"),
    ("mw-id-empty", "", "Malformed environment ID"),
]:
    probe(_pid, f"`digail demos '{_env}' --episodes 1`", _expect)(
        lambda tmp, e=_env: cli(tmp, "demos", e, "--episodes", "1", "--out", "out"))

for _pid, _argv, _expect in [
    ("mw-demos-episodes-0", ["demos", MW, "--episodes", "0", "--out", "out"], "--episodes must be at least 1"),
    ("mw-demos-seed-negative", ["demos", MW, "--episodes", "1", "--seed", "-3", "--out", "out"], "--seed"),
    ("mw-demos-episodes-huge", ["demos", MW, "--episodes", "10000000000000", "--out", "out"],
     "--episodes must be at most"),
    ("mw-expert-steps-0", ["expert", MW, "--steps", "0", "--out", "out"], "--steps"),
    ("mw-evaluate-episodes-0", ["evaluate", "run", "--episodes", "0"], "--episodes must be at least 1"),
]:
    def _mw_cmd(tmp: Path, argv: tuple[str, ...] = tuple(_argv)) -> None:
        if "run" in argv:
            shutil.copytree(RUN, tmp / "run")
        cli(tmp, *argv)

    probe(_pid, f"`digail {' '.join(_argv)}`", _expect)(_mw_cmd)

def _make(**kwargs: object) -> None:
    from digail.envs import make_env

    make_env(MW, **kwargs).close()


probe("mw-option-variation", f"`make_env('{MW}', variation='mt10')` (Python)", "variation must be random or mt1")(
    lambda tmp: _make(variation="mt10"))
probe("mw-option-task", f"`make_env('{MW}', task='pick-place-v9')` (Python)", "unknown Meta-World task")(
    lambda tmp: _make(task="pick-place-v9"))
probe("mw-option-mt1", f"`make_env('{MW}', variation='mt1', mt1_seed=3)` (Python)", None)(
    lambda tmp: _make(variation="mt1", mt1_seed=3))

probe("mw-train-env-mismatch", f"`digail train --env metaworld/hammer-v3 --demos {MW_DEMOS}` (recorded in "
      "pick-place; the same spaces: trained, with a note)", None)(
    lambda tmp: mw_train(tmp, "--env", "metaworld/hammer-v3"))
probe("mw-train-cw-demos", f"`digail train --env {MW} --demos {CW_DEMOS}`", "observations of shape")(
    lambda tmp: mw_train(tmp, "--env", MW, demos=CW_DEMOS))
probe("mw-train-vae-of-another-env", f"`digail train --demos {MW_DEMOS} --vae RUN` with a Pendulum VAE",
      "was trained on Pendulum-v1")(
    lambda tmp: (shutil.copytree(RUN, tmp / "pvae"), mw_train(tmp, "--vae", "pvae", method="digail")))
probe("mw-compose-order-on-pendulum", "`digail compose RUN --order 0,1,2` on a run of 4 codes with "
      "--episodes 1000000000000", "--episodes must be at most")(
    lambda tmp: (shutil.copytree(RUN, tmp / "run"), cli(tmp, "compose", "run", "--order", "0,1,2", "--episodes",
                                                         "1000000000000")))

# ------------------------------------------------------------------------------------------------ presets
for _pid, _preset, _expect in [
    ("preset-unknown", "metaworld2", "unknown preset"),
    ("preset-empty", "", "preset"),
    ("preset-path-missing", "nowhere/metaworld.toml", "preset"),
    ("preset-upper", "METAWORLD", "preset"),
    ("preset-dotdot", "../metaworld", "preset"),
]:
    probe(_pid, f"`digail train --demos {MW_DEMOS} --preset '{_preset}'`", _expect)(
        lambda tmp, pr=_preset: cli(tmp, "train", "--method", "gail", "--demos", MW_DEMOS, "--preset", pr,
                                    "--train.iterations", "1", "--out", "run-new"))


for _pid, _argv, _expect in [
    ("preset-metaworld-on-circleworld", ["--demos", CW_DEMOS, "--preset", "metaworld"], None),
    ("preset-paper-on-metaworld", ["--demos", MW_DEMOS, "--preset", "paper"], "paper"),
    ("preset-fetch-on-metaworld", ["--demos", MW_DEMOS, "--preset", "fetch"], None),
]:
    probe(_pid, f"`digail train --method gail {' '.join(_argv)}` (one iteration)", _expect)(
        lambda tmp, a=tuple(_argv): cli(tmp, "train", "--method", "gail", *a, "--train.iterations", "1",
                                        "--train.ppo.batch-size", "64", "--train.ppo.minibatch-size", "32",
                                        "--train.eval-every", "0", "--out", "run-new"))


# ------------------------------------------------------------------------------------------------ reward settings
for _pid, _flags, _expect in [
    ("reward-kind-unknown", ["--train.imitation.reward", "gan"], "--train.imitation.reward"),
    ("reward-kind-empty", ["--train.imitation.reward", ""], "--train.imitation.reward"),
    ("reward-pu-prior-0", ["--train.imitation.reward", "pu", "--train.imitation.pu-prior", "0"], "pu-prior"),
    ("reward-pu-prior-1", ["--train.imitation.reward", "pu", "--train.imitation.pu-prior", "1"], "pu-prior"),
    ("reward-pu-prior-nan", ["--train.imitation.reward", "pu", "--train.imitation.pu-prior", "nan"], "pu-prior"),
    ("reward-pu-prior-text", ["--train.imitation.pu-prior", "half"], "pu-prior"),
    ("reward-dropout-1", ["--train.imitation.disc-dropout", "1"], "disc-dropout"),
    ("reward-dropout-negative", ["--train.imitation.disc-dropout", "-0.1"], "disc-dropout"),
    ("reward-noise-inf", ["--train.imitation.disc-noise", "inf"], "disc-noise"),
    ("reward-weight-decay-negative", ["--train.imitation.disc-weight-decay", "-1"], "disc-weight-decay"),
    ("reward-ot-top-k-0", ["--train.imitation.reward", "ot", "--train.imitation.ot-top-k", "0"], "ot-top-k"),
    ("reward-ot-top-k-float", ["--train.imitation.ot-top-k", "1.5"], "ot-top-k"),
    ("reward-ot-epsilon-0", ["--train.imitation.reward", "ot", "--train.imitation.ot-epsilon", "0"], "ot-epsilon"),
    ("reward-ot-epsilon-negative", ["--train.imitation.ot-epsilon", "-0.05"], "ot-epsilon"),
    ("reward-ot-iterations-0", ["--train.imitation.ot-iterations", "0"], "ot-iterations"),
    ("reward-ot-scale-inf", ["--train.imitation.ot-scale", "inf"], "ot-scale"),
    ("reward-ot-code-penalty-negative", ["--train.imitation.ot-code-penalty", "-1"], "ot-code-penalty"),
    ("reward-ot-time-weight-nan", ["--train.imitation.ot-time-weight", "nan"], "ot-time-weight"),
    ("reward-bc-schedule-unknown", ["--train.imitation.bc-schedule", "sometimes"], "bc-schedule"),
    ("reward-qfilter-on-ppo", ["--train.imitation.bc-schedule", "qfilter"], "qfilter"),
    ("reward-ot-top-k-more-than-demos", ["--train.imitation.reward", "ot", "--train.imitation.ot-top-k", "100000",
                                         "--demos-episodes", "4"], None),
    ("reward-ot-epsilon-tiny", ["--train.imitation.reward", "ot", "--train.imitation.ot-epsilon", "1e-300"],
     "--train.imitation.ot-epsilon must be between 0.0001 and 10000"),
    ("reward-ot-scale-huge", ["--train.imitation.reward", "ot", "--train.imitation.ot-scale", "1e300"],
     "--train.imitation.ot-scale must be between 0 and 1000"),
    ("reward-ot-subtask-on-gail", ["--train.imitation.reward", "ot-subtask"], "ot-subtask"),
    ("reward-relabel-no-goal", ["--train.imitation.relabel-goals", "4"], "goal-conditioned"),
    ("reward-relabel-negative", ["--train.imitation.relabel-goals", "-1"], "relabel-goals"),
    ("reward-relabel-with-ot", ["--train.imitation.reward", "ot", "--train.imitation.relabel-goals", "2"],
     "optimal-transport"),
]:
    probe(_pid, f"`digail train --method gail` (Circle-World) with `{' '.join(_flags)}`", _expect)(
        lambda tmp, f=tuple(_flags): cw_train(tmp, *f))



# ------------------------------------------------------------------------------------------------ report pages
def _report_targets(tmp: Path) -> None:
    """A run folder (a copy of a committed one, with a checkpoint) and what a page could be aimed at beside it: a
    user's page, a home folder's .bashrc, a link to the user's page, a FIFO, a socket (standing for a device) and a
    user's figure where a comparison's would go."""
    import socket

    shutil.copytree(RUN, tmp / "run")
    (tmp / "run" / "checkpoint.pt").write_bytes(b"a checkpoint\n")
    (tmp / "mine.html").write_text("<html>a user's page</html>\n")
    (tmp / "home").mkdir()
    (tmp / "home" / ".bashrc").write_text("export PATH=$PATH\n")
    (tmp / "link.html").symlink_to(tmp / "mine.html")
    os.mkfifo(tmp / "fifo")
    with socket.socket(socket.AF_UNIX) as sock:  # the file stays once the socket is closed
        sock.bind(str(tmp / "sock"))
    (tmp / "c_learning_curves.png").write_bytes(b"\x89PNG\r\n\x1a\na user's figure")


for _pid, _argv, _what, _expect in [
    ("report-out-model", ["run", "--out", "run/model.pt", "--force"], "the run's `model.pt`, with `--force`",
     "is the run's file model.pt"),
    ("report-out-config", ["run", "--out", "run/config.json"], "the run's `config.json`",
     "is the run's file config.json"),
    ("report-out-checkpoint", ["run", "--out", "run/checkpoint.pt", "--force"],
     "the run's `checkpoint.pt`, with `--force`", "is the run's file checkpoint.pt"),
    ("report-out-inside-figures", ["run", "--out", "run/figures/page.html"], "a new page inside the run's figures",
     "is inside the run's folder figures"),
    ("report-out-run", ["run", "--out", "run", "--force"], "the run folder itself, with `--force`", "holds the run's"),
    ("report-out-users-page", ["run", "--out", "mine.html"], "a user's `mine.html`", "already exists"),
    ("report-out-users-page-force", ["run", "--out", "mine.html", "--force"], "a user's `mine.html`, with `--force`",
     "is not a report page digail wrote"),
    ("report-out-bashrc", ["run", "--out", "home/.bashrc", "--force"], "a user's `.bashrc`, with `--force`",
     "is not a report page digail wrote"),
    ("report-out-link", ["run", "--out", "link.html", "--force"], "a link to a user's page, with `--force`",
     "is a symbolic link"),
    ("report-out-fifo", ["run", "--out", "fifo", "--force"], "a FIFO, with `--force`", "is a FIFO"),
    ("report-out-socket", ["run", "--out", "sock", "--force"], "a Unix socket (as a device), with `--force`",
     "is a socket"),
    ("report-compare-users-page", ["--compare", "run", "--out", "mine.html", "--force"],
     "`--compare`: a user's `mine.html`, with `--force`", "is not a report page digail wrote"),
    ("report-compare-users-figure", ["--compare", "run", "--out", "c.html"],
     "`--compare`: a new page whose figure's name is a user's file", "c_learning_curves.png already exists"),
    ("report-compare-users-figure-force", ["--compare", "run", "--out", "c.html", "--force"],
     "`--compare`: a new page whose figure's name is a user's file, with `--force`", "is not a figure digail drew"),
    ("report-out-new", ["run", "--out", "page.html"], "a new page", None),
    ("report-own-page", ["run"], "the run's own `report.html` (rewritten on every call)", None),
]:
    probe(_pid, f"`digail report {' '.join(_argv)} --no-figures`: {_what}", _expect, setup=_report_targets)(
        lambda tmp, a=tuple(_argv): cli(tmp, "report", *a, "--no-figures"))


@probe("report-again-force", "`digail report run --out page.html --force` over its own earlier page", None,
       setup=_report_targets)
def _report_again(tmp: Path) -> None:
    cli(tmp, "report", "run", "--no-figures", "--out", "page.html")
    cli(tmp, "report", "run", "--no-figures", "--out", "page.html", "--force")


@probe("report-device-check", "the page check of `--out /dev/null --force` (the check alone, which writes nothing)",
       "is a character device")
def _report_device(tmp: Path) -> None:
    from digail.commands.report import check_page_path

    check_page_path(Path("/dev/null"), [], force=True)


# ------------------------------------------------------------------------------------------------ folder outputs
_INPUTS: list[Path] = []
"""the folder `_inputs` fills once per test process: a copy of the shipped Circle-World dataset and a VAE on it"""


def _inputs(tmp: Path) -> None:
    """cwd/ (a copy of the shipped Circle-World dataset), vae/ (a SMOKE VAE pre-trained on it), ex/ (a folder digail
    made holding an expert file) and a FIFO, in `tmp`: what a folder output could be aimed at."""
    if not _INPUTS:
        import atexit
        import tempfile

        made = Path(tempfile.mkdtemp(prefix="digail-probe-inputs-"))
        atexit.register(shutil.rmtree, made, True)  # made once per process, gone with it
        shutil.copytree(ROOT / "src" / "digail" / "datasets" / "digail" / "circleworld" / "expert-v0", made / "cwd")
        cli(made, "pretrain", "--demos", "cwd", "--codes", "2", "--preset", "smoke", "--out", "vae")
        _INPUTS.append(made)
    for name in ("cwd", "vae"):
        shutil.copytree(_INPUTS[0] / name, tmp / name, symlinks=True)
    (tmp / "vae" / "config.json").write_text((tmp / "vae" / "config.json").read_text().replace(
        str(_INPUTS[0]), str(tmp)))
    (tmp / "ex").mkdir()
    (tmp / "ex" / MARKER).write_text("\n")
    (tmp / "ex" / "expert.zip").write_bytes(b"an expert\n")
    os.mkfifo(tmp / "fifo")


_TRAIN = ["--preset", "smoke", "--train.iterations", "1"]
for _pid, _argv, _expect in [
    ("out-pretrain-input", ["pretrain", "--demos", "cwd", "--codes", "2", "--out", "cwd", "--force"],
     "is the input demonstrations"),
    ("out-pretrain-inside-input", ["pretrain", "--demos", "cwd", "--codes", "2", "--out", "cwd/data/vae"],
     "is inside the input demonstrations"),
    ("out-pretrain-holds-input", ["pretrain", "--demos", "cwd", "--codes", "2", "--out", ".", "--force"],
     "holds the input demonstrations"),
    ("out-pretrain-fifo", ["pretrain", "--demos", "cwd", "--codes", "2", "--out", "fifo", "--force"], "is a FIFO"),
    ("out-train-vae", ["train", "--method", "digail", "--demos", "cwd", "--vae", "vae", *_TRAIN, "--out", "vae",
                       "--force"], "is the VAE run"),
    ("out-train-inside-vae", ["train", "--method", "digail", "--demos", "cwd", "--vae", "vae", *_TRAIN, "--out",
                              "vae/gail"], "is inside the VAE run"),
    ("out-train-input", ["train", "--method", "gail", "--demos", "cwd", *_TRAIN, "--out", "cwd", "--force"],
     "is the input demonstrations"),
    ("out-run-input", ["run", CW, "--demos", "cwd", "--preset", "smoke", "--out", "cwd", "--force"],
     "is the input demonstrations"),
    ("out-demos-expert", ["demos", CW, "--episodes", "2", "--expert", "ex/expert.zip", "--out", "ex", "--force"],
     "holds the expert"),
    ("out-demos-fifo", ["demos", CW, "--episodes", "2", "--out", "fifo"], "is a FIFO"),
    ("out-generate-inside-input", ["generate", "--demos", "cwd", "--out", "cwd/data/more"],
     "is inside the input demonstrations"),
]:
    probe(_pid, f"`digail {' '.join(_argv)}`", _expect, setup=_inputs)(lambda tmp, a=tuple(_argv): cli(tmp, *a))


# ------------------------------------------------------------------------------------------------ sizes and ranges
for _pid, _argv, _expect in [
    ("size-codes-huge", ["pretrain", "--demos", CW_DEMOS, "--codes", "100000", "--out", "vae"],
     "--codes must be between 1 and 256"),
    ("size-codes-3e9", ["pretrain", "--demos", CW_DEMOS, "--codes", "3000000000", "--out", "vae"],
     "--codes must be between 1 and 256"),
    ("size-max-codes-huge", ["pretrain", "--demos", CW_DEMOS, "--codes", "auto", "--max-codes", "100000", "--out",
                             "vae"], "--max-codes must be between 1 and 256"),
    ("size-vae-batch-huge", ["pretrain", "--demos", CW_DEMOS, "--codes", "2", "--vae.batch-size", "10000000000",
                             "--out", "vae"], "--vae.batch-size must be at most"),
    ("size-iterations-huge", ["train", "--method", "gail", "--demos", CW_DEMOS, "--train.iterations",
                              "1000000000000", "--out", "run-new"], "--train.iterations must be at most"),
    ("size-ppo-batch-huge", ["train", "--method", "gail", "--demos", CW_DEMOS, "--train.ppo.batch-size",
                             "10000000000", "--out", "run-new"], "--train.ppo.batch-size must be at most"),
    ("size-ppo-envs-huge", ["train", "--method", "gail", "--demos", CW_DEMOS, "--train.ppo.num-envs", "100000",
                            "--out", "run-new"], "--train.ppo.num-envs must be at most"),
    ("size-sac-batch-huge", ["train", "--method", "gail", "--demos", CW_DEMOS, "--train.learner", "sac",
                             "--train.sac.batch-size", "10000000000", "--out", "run-new"],
     "--train.sac.batch-size must be at most"),
    ("size-vae-epochs-huge", ["pretrain", "--demos", CW_DEMOS, "--codes", "2", "--vae.epochs", "1000000000000",
                              "--out", "vae"], "--vae.epochs must be between 0 and 1,000,000"),
    ("size-vae-hidden-huge", ["pretrain", "--demos", CW_DEMOS, "--codes", "2", "--vae.hidden", "10000000000",
                              "--out", "vae"], "--vae.hidden must be sizes of 1 to 16,384"),
    ("size-train-hidden-huge", ["train", "--method", "gail", "--demos", CW_DEMOS, "--train.hidden", "64",
                                "10000000000", "--out", "run-new"], "--train.hidden must be sizes of 1 to 16,384"),
    ("size-sac-hidden-huge", ["train", "--method", "gail", "--demos", CW_DEMOS, "--train.learner", "sac",
                              "--train.sac.hidden", "10000000000", "--out", "run-new"],
     "--train.sac.hidden must be sizes of 1 to 16,384"),
    ("size-expert-steps-huge", ["expert", "Pendulum-v1", "--steps", "1000000000000", "--out", "out"],
     "--steps must be at most 1,000,000,000"),
    ("size-generate-attempts-huge", ["generate", "--demos", "digail/fetchpickandplace/expert-v0", "--attempts",
                                     "1000000000", "--out", "out"], "--attempts must be at most 1,000,000"),
    ("size-episodes-evaluate", ["evaluate", str(RUN), "--episodes", "10000000"],
     "--episodes must be at most 1,000,000"),
    ("size-episodes-compose", ["compose", str(RUN), "--schedule", "0:10", "--episodes", "4294967296"],
     "--episodes must be at most 1,000,000"),
    ("size-episodes-demos", ["demos", CW, "--episodes", "10000000", "--out", "out"],
     "--episodes must be at most 1,000,000"),
    ("size-episodes-run", ["run", CW, "--episodes", "10000000", "--out", "run-new"],
     "--episodes must be at most 1,000,000"),
    ("size-episodes-video", ["video", str(RUN), "--episodes", "101"], "--episodes must be at most 100,"),
    ("size-video-search", ["video", str(RUN), "--outcome", "success", "--search", "10000000"],
     "--search must be at most 1,000,000"),
]:
    probe(_pid, f"`digail {' '.join(_argv)}`".replace(str(RUN), "RUN"), _expect)(
        lambda tmp, a=tuple(_argv): cli(tmp, *a))


@probe("size-demos-memory", "`digail demos digail/CircleWorld-v0 --episodes 1000` with 1 MiB of memory available",
       "of memory (episodes of up to")
def _demos_memory(tmp: Path) -> None:
    import digail.utils

    real = digail.utils.available_memory
    digail.utils.available_memory = lambda: 2**20
    try:
        cli(tmp, "demos", CW, "--episodes", "1000", "--out", "out")
    finally:
        digail.utils.available_memory = real

for _pid, _flags, _expect in [
    ("range-relabel-huge", ["--train.imitation.relabel-goals", "1000000000"], "from 0 to 1000"),
    ("range-relabel-1e30", ["--train.imitation.relabel-goals", "1" + "0" * 30], "from 0 to 1000"),
    ("range-ot-iterations-huge", ["--train.imitation.reward", "ot", "--train.imitation.ot-iterations",
                                  "1000000000000"], "--train.imitation.ot-iterations must be at most 1000"),
    ("range-weight-decay-huge", ["--train.imitation.disc-weight-decay", "1e300"],
     "--train.imitation.disc-weight-decay must be between 0 and 1"),
    ("range-ot-scale-max", ["--train.imitation.reward", "ot", "--train.imitation.ot-scale", "1e308"],
     "--train.imitation.ot-scale must be between 0 and 1000"),
    ("range-ot-scale-euclidean", ["--train.imitation.reward", "ot", "--train.imitation.ot-cost", "euclidean",
                                  "--train.imitation.ot-scale", "1e30"], "--train.imitation.ot-scale must be between"),
    ("range-ot-epsilon-huge", ["--train.imitation.reward", "ot", "--train.imitation.ot-epsilon", "1e300"],
     "--train.imitation.ot-epsilon must be between"),
    ("range-ot-epsilon-smallest", ["--train.imitation.reward", "ot", "--train.imitation.ot-epsilon", "1e-4",
                                   "--train.imitation.ot-cost", "euclidean"], None),
    ("range-ot-scale-largest", ["--train.imitation.reward", "ot", "--train.imitation.ot-cost", "euclidean",
                                "--train.imitation.ot-scale", "1000"], None),
]:
    probe(_pid, f"`digail train --method gail` (Circle-World) with `{' '.join(_flags)}`", _expect)(
        lambda tmp, f=tuple(_flags): cw_train(tmp, *f))



# ---------------------------------------------------------------------------------------- tests beyond the probes
FORCE_COMMANDS = {
    "train": ["train", "--method", "gail", "--demos", CW_DEMOS, "--preset", "smoke", "--out", "{out}", "--force"],
    "run": ["run", CW, "--preset", "smoke", "--out", "{out}", "--force"],
    "pretrain": ["pretrain", "--demos", CW_DEMOS, "--preset", "smoke", "--out", "{out}", "--force"],
    "demos": ["demos", "digail/FourRooms-v0", "--episodes", "2", "--out", "{out}", "--force"],
    "import": ["import", "{npz}", "--out", "{out}", "--force"],
}


@pytest.fixture
def npz(tmp_path: Path) -> Path:
    rng = np.random.default_rng(0)
    path = tmp_path / "demos.npz"
    np.savez(path, observations=rng.normal(size=(20, 3)).astype(np.float32),
             actions=rng.normal(size=(20, 1)).astype(np.float32), episode_ends=np.array([10, 20]))
    return path


def _argv(name: str, out: Path | str, npz: Path) -> list[str]:
    return [a.replace("{out}", str(out)).replace("{npz}", str(npz)) for a in FORCE_COMMANDS[name]]


@pytest.mark.parametrize("name", list(FORCE_COMMANDS))
def test_force_refuses_a_folder_digail_did_not_make(name, tmp_path, npz, capsys):
    victim = users_folder(tmp_path / "mine")
    before = tree(victim)
    refusal(_argv(name, victim, npz), "is not a folder digail made", "--force replaces only those")
    assert tree(victim) == before and not (victim / MARKER).exists()


@pytest.mark.parametrize("name", ["train", "pretrain", "import"])
def test_force_never_deletes_the_current_directory_or_a_folder_above_it(name, tmp_path, npz, capsys, monkeypatch):
    inner = tmp_path / "a" / "inner"
    inner.mkdir(parents=True)
    (inner / "work.txt").write_text("unsaved\n")
    (inner / MARKER).write_text("even one digail made\n")  # the marker does not make the cwd replaceable
    (tmp_path / "a" / MARKER).write_text("nor a folder above it\n")
    before = tree(tmp_path / "a")
    monkeypatch.chdir(inner)
    for out, what in ((".", "the current directory"), ("..", "a folder holding the current directory")):
        refusal(_argv(name, out, npz), f"--force would delete {out}, {what}")
    assert tree(tmp_path / "a") == before


def test_force_never_deletes_the_home_folder_or_a_filesystem_root(tmp_path, monkeypatch):
    home = tmp_path / "home"
    home.mkdir()
    (home / MARKER).write_text("\n")
    monkeypatch.setenv("HOME", str(home))
    monkeypatch.chdir(tmp_path)
    with pytest.raises(UserError, match="the home folder"):
        check_replaceable(home)
    with pytest.raises(UserError, match="--force would delete /"):
        check_replaceable(Path("/"))


def test_force_refuses_a_file_and_a_link_to_a_users_folder(tmp_path, npz, capsys):
    file = tmp_path / "out"
    file.write_text("a user's file\n")
    refusal(_argv("import", file, npz), "is a file, and --force replaces only a folder")
    assert file.read_text() == "a user's file\n"
    victim = users_folder(tmp_path / "mine")
    link = tmp_path / "link"
    link.symlink_to(victim)
    refusal(_argv("import", link, npz), "is not a folder digail made")
    assert link.is_symlink() and tree(victim, stamps=False) == tree(users_folder(tmp_path / "again"), stamps=False)


def test_force_replaces_what_digail_made_and_marks_every_new_folder(tmp_path, npz, capsys):
    out = tmp_path / "data"
    assert main(_argv("import", out, npz)) == 0
    assert (out / MARKER).is_file()
    (out / "extra.txt").write_text("added later\n")
    assert main(_argv("import", out, npz)) == 0  # the marker says digail made it: replaced whole
    assert (out / MARKER).is_file() and not (out / "extra.txt").exists()
    empty = tmp_path / "empty"
    empty.mkdir()
    assert main(_argv("import", empty, npz)) == 0  # an empty folder loses nothing
    capsys.readouterr()


def test_folders_from_before_the_marker_count_as_digails():
    """The committed run folders and the shipped datasets carry no marker; their records make them digail's."""
    runs = sorted((ROOT / "benchmarks" / "results" / "runs").iterdir())
    assert runs and all(digail_made(r) for r in runs if r.is_dir())
    datasets = sorted((ROOT / "src" / "digail" / "datasets" / "digail").glob("*/expert-v0"))
    assert datasets and all(digail_made(d) for d in datasets)


def test_a_json_file_alone_does_not_make_a_folder_digails(tmp_path):
    folder = users_folder(tmp_path / "mine")
    (folder / "config.json").write_text('{"lr": 0.1}\n')  # some other tool's config
    assert not digail_made(folder)
    (folder / "config.json").write_text("[1, 2]\n")
    assert not digail_made(folder)


def test_a_refused_run_leaves_no_folder_behind(tmp_path, npz, capsys):
    out = tmp_path / "run"
    refusal(["run", CW, "--preset", "smoke", "--demos-episodes", "100000", "--out", str(out)],
            "--demos-episodes 100000 asks for more episodes")
    refusal(["run", "Pendulum-v1", "--demos", str(npz), "--demos-episodes", "50", "--out", str(out)],
            "--demos-episodes 50 asks for more episodes")
    assert not out.exists()
    assert sorted(p.name for p in tmp_path.iterdir()) == ["demos.npz"]


def test_a_refused_subset_after_recording_removes_the_folder(tmp_path, monkeypatch, capsys):
    """Demonstrations recorded into the run folder, then found too few: the folder goes, so that the corrected
    command is not refused as "already exists"."""
    import digail.commands.run as run_mod

    def refuse(*_: object, **__: object) -> None:
        (tmp_path / "run" / "demos").mkdir()  # what recording them would have left
        raise run_mod._SubsetRefused("--demos-episodes 9 asks for more episodes than the dataset's 2; pass at most "
                                     "that many.")

    monkeypatch.setattr(run_mod, "_run_stages", refuse)
    refusal(["run", CW, "--preset", "smoke", "--out", str(tmp_path / "run")], "asks for more episodes")
    assert not (tmp_path / "run").exists()


def test_a_lock_file_that_is_a_folder_is_one_sentence(tmp_path, capsys):
    run = tmp_path / "run"
    (run / ".digail.lock").mkdir(parents=True)
    with pytest.raises(UserError, match="is a folder, not digail's lock file"), run_dir_lock(run):
        pass
    refusal(["segment", str(run)], "is a folder, not digail's lock file")


@pytest.mark.parametrize("argv", [
    ["train", "--method", "gail", "--demos", CW_DEMOS, "--preset", "smoke", "--out", "OUT"],
    ["pretrain", "--demos", "DEMOS", "--preset", "smoke"],
    ["report", "OUT"],
    ["import", "DEMOS", "--out", "OUT"],
])
def test_a_path_that_is_not_utf8_is_refused_up_front(argv, tmp_path, capsys, monkeypatch):
    bad = "r\udcffn"  # the byte 0xff in a file name, as Python shows it
    monkeypatch.chdir(tmp_path)
    words = [a.replace("OUT", bad).replace("DEMOS", bad + ".npz") for a in argv]
    refusal(words, "is not valid UTF-8", "r\\xffn")
    assert list(tmp_path.iterdir()) == []


def test_a_non_finite_loss_names_the_setting_set_away_from_its_default(
        monkeypatch: pytest.MonkeyPatch, tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """A NaN loss that happens within the checked ranges names the reward setting most likely responsible (one set
    away from its default), not the learning rate."""
    from digail.algos.gail.trainer import GAIL
    from digail.errors import TrainingError

    def nan_loss(self: object, **_: object) -> None:
        raise TrainingError("non-finite loss (policy) at iteration 1; the last good checkpoint is kept - lower the "
                            "learning rate or check the demonstrations.")

    monkeypatch.setattr(GAIL, "train", nan_loss)
    argv = ["train", "--method", "gail", "--demos", CW_DEMOS, "--preset", "smoke", "--train.iterations", "1"]
    code = main([*argv, "--train.imitation.disc-weight-decay", "0.5", "--out", str(tmp_path / "a")])
    err = [ln for ln in capsys.readouterr().err.splitlines() if ln.startswith("digail train: error:")]
    assert code == 1 and not (tmp_path / "a").exists()
    assert len(err) == 1 and "the likely cause is --train.imitation.disc-weight-decay 0.5" in err[0], err


@pytest.mark.parametrize(("settings", "named"), [
    ({"reward": "ot", "ot_epsilon": 1e-4}, "--train.imitation.ot-epsilon 0.0001"),
    ({"reward": "ot", "ot_cost": "euclidean", "ot_scale": 1000.0},
     "--train.imitation.ot-cost euclidean and --train.imitation.ot-scale 1000.0"),
    ({"disc_weight_decay": 0.5, "ot_scale": 3.0}, "--train.imitation.disc-weight-decay 0.5,"),  # ot: not D's reward
    ({"disc_lr": 1.0}, "--train.imitation.disc-lr 1.0"),
    ({"logits_to_reward": "logit"}, "--train.imitation.logits-to-reward logit"),
    ({"reward": "pu", "pu_prior": 0.9}, "--train.imitation.pu-prior 0.9"),
])
def test_the_likely_cause_of_a_non_finite_loss_is_the_setting_moved(settings: dict[str, Any], named: str) -> None:
    """Each reward setting whose extreme values make a loss non-finite is named when it was moved, only those of
    the reward in use; at the defaults, or under other advice, the sentence stays as it was."""
    from digail.checks import GENERIC_CAUSE, likely_cause
    from digail.imitation_config import ImitationConfig

    message = "non-finite loss (policy) at iteration 1; nothing saved - " + GENERIC_CAUSE + "."
    moved = ImitationConfig(**settings)
    named_it = likely_cause(message, moved)
    assert f"the likely cause is {named}" in named_it and GENERIC_CAUSE not in named_it, named_it
    assert named_it.endswith("set away from the default: try a value nearer it (or lower the learning rate).")
    assert likely_cause(message, ImitationConfig()) == message
    assert likely_cause("non-finite loss; check the view.", moved) == "non-finite loss; check the view."


# ------------------------------------------------------------------------------------------------ the probes
@pytest.mark.parametrize("p", PROBES, ids=[p.id for p in PROBES])
def test_probe(p: Probe, tmp_path: Path, request: pytest.FixtureRequest) -> None:
    check_probe(p, tmp_path, request.getfixturevalue("base") if p.on_base else None)


def test_the_reliability_page_lists_every_probe() -> None:
    assert_published(PROBES, "Probes: command-line arguments and output paths")
