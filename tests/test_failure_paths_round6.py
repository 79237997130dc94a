"""Failure paths, sixth round: bad input on the surfaces added since the fifth (Meta-World env ids, presets and
datasets, the imitation-reward settings, robosuite-made robomimic files) and the fifth round's classes tried again
on them (code named by data, D's views, messages).

Each probe is what a user might try and what digail must give back: accepted, or refused with one sentence holding
the expected phrase (exit status 2 from the CLI, no traceback), with no output folder left behind. The same probes,
with what each gets, are the sixth round's table in the reliability page (docs/reference/errors.md;
`python scripts/probe_table.py --round 6`).
"""

from __future__ import annotations

import json
import shutil
import sys
from collections.abc import Callable
from pathlib import Path

import h5py
import numpy as np
import pytest
from test_failure_paths_round4 import CW, CW_DEMOS, Probe, sweep_check
from test_failure_paths_round5_code import assert_answer, outcome, plant, ran

from digail.errors import UserError

pytest.importorskip("metaworld")

PROBES: list[Probe] = []
REPO = Path(__file__).resolve().parents[1]
MW = "metaworld/pick-place-v3"
MW_DEMOS = "digail/metaworld-pick-place/expert-v0"
ROBOSUITE = REPO / "tests" / "data" / "robosuite"
RUN = REPO / "benchmarks" / "results" / "runs" / "pendulum_vae_s2"


def probe(pid: str, what: str, expect: str | None) -> Callable[[Callable[[Path], object]], Callable[[Path], object]]:
    def add(fn: Callable[[Path], object]) -> Callable[[Path], object]:
        PROBES.append(Probe(pid, what, fn, expect))
        return fn

    return add


def cli(tmp: Path, *argv: str) -> None:
    """Round four's `cli`, also taking status 1: a training that cannot go on (a NaN loss) is one sentence too."""
    import contextlib
    import io
    import os

    from digail.cli import main

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
    assert code in (1, 2) and len(lines) == 1 and ": error: " in lines[0], (code, text)
    raise UserError(lines[0].split(": error: ", 1)[1] + (" (status 1)" if code == 1 else ""))


def mw_train(tmp: Path, *flags: str, demos: str = MW_DEMOS, method: str = "gail") -> None:
    """`digail train` on the shipped Meta-World pick-place demonstrations, one smoke iteration."""
    cli(tmp, "train", "--method", method, "--demos", demos, "--preset", "smoke", "--train.iterations", "1", *flags,
        "--out", "run-new")


def cw_train(tmp: Path, *flags: str) -> None:
    """`digail train` GAIL on Circle-World, one smoke iteration (the reward settings' probes)."""
    cli(tmp, "train", "--method", "gail", "--demos", CW_DEMOS, "--preset", "smoke", "--train.iterations", "1",
        *flags, "--out", "run-new")


# ------------------------------------------------------------------------------------------------ Meta-World env ids
def cli_process(tmp: Path, *argv: str) -> None:
    """`digail argv` in a process of its own, stderr as a shell shows it (warnings included, which the test
    harness would otherwise capture): one line on refusal."""
    import os
    import subprocess

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


# ------------------------------------------------------------------------------------------------ Meta-World datasets
def _mw_copy(tmp: Path) -> Path:
    from digail.data.minari_io import resolve_dataset

    src = resolve_dataset(MW_DEMOS)
    shutil.copytree(src, tmp / "ds")
    return tmp / "ds"


def _damaged(edit: Callable[[Path], None], *argv: str) -> Callable[[Path], None]:
    def run(tmp: Path) -> None:
        ds = _mw_copy(tmp)
        edit(ds)
        cli(tmp, *(a.replace("DS", "ds") for a in argv))

    return run


def _h5(ds: Path, fn: Callable[[h5py.File], None]) -> None:
    with h5py.File(ds / "data" / "main_data.hdf5", "r+") as f:
        fn(f)


def _set_obs(f: h5py.File, value: float, row: int = 3) -> None:
    obs = f["episode_0/observations"][...].astype(np.float64)  # as a float64 env records them
    obs[row, 0] = value
    del f["episode_0/observations"]
    f["episode_0/observations"] = obs


def _meta(ds: Path, change: Callable[[dict], object]) -> None:
    path = ds / "data" / "metadata.json"
    meta = json.loads(path.read_text())
    change(meta)
    path.write_text(json.dumps(meta))


PRETRAIN = ("pretrain", "--demos", "DS", "--codes", "2", "--preset", "smoke", "--vae.steps", "2", "--vae.init-steps",
            "0", "--out", "vae")
for _pid, _what, _edit, _argv, _expect in [
    ("mwds-obs-nan", "an observation NaN", lambda ds: _h5(ds, lambda f: _set_obs(f, float("nan"))), PRETRAIN,
     "NaN or inf"),
    ("mwds-obs-inf", "an observation inf", lambda ds: _h5(ds, lambda f: _set_obs(f, float("inf"))), PRETRAIN,
     "NaN or inf"),
    ("mwds-obs-1e300", "a float64 observation of 1e300", lambda ds: _h5(ds, lambda f: _set_obs(f, 1e300)), PRETRAIN,
     "float32"),
    ("mwds-actions-cut", "episode 0's actions one short",
     lambda ds: _h5(ds, lambda f: (f.__setitem__("a", f["episode_0/actions"][:-1]),
                                   f.__delitem__("episode_0/actions"), f.move("a", "episode_0/actions"))),
     PRETRAIN, "episode 0"),
    ("mwds-no-episodes", "its episodes removed",
     lambda ds: _h5(ds, lambda f: [f.__delitem__(k) for k in list(f.keys())]), PRETRAIN, "ds"),
    ("mwds-hdf5-truncated", "main_data.hdf5 cut in half",
     lambda ds: (ds / "data" / "main_data.hdf5").write_bytes((ds / "data" / "main_data.hdf5").read_bytes()[:50000]),
     PRETRAIN, "ds"),
    ("mwds-metadata-list", "metadata.json a JSON list", lambda ds: (ds / "data" / "metadata.json").write_text("[]"),
     PRETRAIN, "metadata.json"),
    ("mwds-env-spec-other-task", "env_spec naming metaworld/hammer-v3 and `--env` pick-place (39-d either way: "
     "trained, with a note)",
     lambda ds: _meta(ds, lambda m: m.__setitem__("env_spec", m["env_spec"].replace("pick-place", "hammer"))),
     ("train", "--method", "gail", "--demos", "DS", "--env", MW, "--preset", "smoke", "--train.iterations", "1",
      "--out", "run-new"), None),
    ("mwds-env-spec-garbage", "env_spec that is not JSON", lambda ds: _meta(ds, lambda m: m.__setitem__(
        "env_spec", "{not json")), PRETRAIN, "cannot read the Minari dataset"),
    ("mwds-env-spec-module", "env_spec naming an entry point `evil6:Env` (evil6.py beside it)",
     lambda ds: (_meta(ds, lambda m: m.__setitem__("env_spec", m["env_spec"].replace(
         "metaworld/pick-place-v3", "Evil6-v0").replace("digail.envs.metaworld:MetaWorldEnv", "evil6:Env"))),
                 plant(ds.parent, "evil6")),
     ("train", "--method", "gail", "--demos", "DS", "--preset", "smoke", "--train.iterations", "1", "--out",
      "run-new"), "pass --env evil6:Evil6-v0 to allow it"),
    ("mwds-labels-partial", "subtask labels removed from episode 1 only",
     lambda ds: _h5(ds, lambda f: f.__delitem__("episode_1/infos/subtask") if "episode_1/infos/subtask" in f else
                    None), PRETRAIN, "labels"),
]:
    probe(_pid, f"`digail {_argv[0]}` on a copy of the shipped Meta-World pick-place dataset with {_what}", _expect)(
        _damaged(_edit, *_argv))

probe("mwds-demos-episodes-too-many", f"`digail pretrain --demos {MW_DEMOS} --demos-episodes 1000`", "1000")(
    lambda tmp: cli(tmp, "pretrain", "--demos", MW_DEMOS, "--codes", "2", "--demos-episodes", "1000", "--out", "vae"))
probe("mwds-demos-subsample-0", f"`digail pretrain --demos {MW_DEMOS} --demos-subsample 0`",
      "--demos-subsample must be at least 1")(
    lambda tmp: cli(tmp, "pretrain", "--demos", MW_DEMOS, "--codes", "2", "--demos-subsample", "0", "--out", "vae"))
probe("mwds-codes-0", f"`digail pretrain --demos {MW_DEMOS} --codes 0`", "--codes must be at least 1")(
    lambda tmp: cli(tmp, "pretrain", "--demos", MW_DEMOS, "--codes", "0", "--out", "vae"))
probe("mwds-id-typo", "`digail pretrain --demos digail/metaworld-pick-plac/expert-v0`", "no Minari dataset")(
    lambda tmp: cli(tmp, "pretrain", "--demos", "digail/metaworld-pick-plac/expert-v0", "--codes", "2", "--out",
                    "vae"))

# ------------------------------------------------------------------------------------------------ reward settings
for _pid, _flags, _expect in [
    ("reward-kind-unknown", ["--train.imitation.kind", "gan"], "--train.imitation.kind"),
    ("reward-kind-empty", ["--train.imitation.kind", ""], "--train.imitation.kind"),
    ("reward-pu-prior-0", ["--train.imitation.kind", "pu", "--train.imitation.pu-prior", "0"], "pu-prior"),
    ("reward-pu-prior-1", ["--train.imitation.kind", "pu", "--train.imitation.pu-prior", "1"], "pu-prior"),
    ("reward-pu-prior-nan", ["--train.imitation.kind", "pu", "--train.imitation.pu-prior", "nan"], "pu-prior"),
    ("reward-pu-prior-text", ["--train.imitation.pu-prior", "half"], "pu-prior"),
    ("reward-dropout-1", ["--train.imitation.disc-dropout", "1"], "disc-dropout"),
    ("reward-dropout-negative", ["--train.imitation.disc-dropout", "-0.1"], "disc-dropout"),
    ("reward-noise-inf", ["--train.imitation.disc-noise", "inf"], "disc-noise"),
    ("reward-weight-decay-negative", ["--train.imitation.disc-weight-decay", "-1"], "disc-weight-decay"),
    ("reward-ot-top-k-0", ["--train.imitation.kind", "ot", "--train.imitation.ot-top-k", "0"], "ot-top-k"),
    ("reward-ot-top-k-float", ["--train.imitation.ot-top-k", "1.5"], "ot-top-k"),
    ("reward-ot-epsilon-0", ["--train.imitation.kind", "ot", "--train.imitation.ot-epsilon", "0"], "ot-epsilon"),
    ("reward-ot-epsilon-negative", ["--train.imitation.ot-epsilon", "-0.05"], "ot-epsilon"),
    ("reward-ot-iterations-0", ["--train.imitation.ot-iterations", "0"], "ot-iterations"),
    ("reward-ot-scale-inf", ["--train.imitation.ot-scale", "inf"], "ot-scale"),
    ("reward-ot-code-penalty-negative", ["--train.imitation.ot-code-penalty", "-1"], "ot-code-penalty"),
    ("reward-ot-time-weight-nan", ["--train.imitation.ot-time-weight", "nan"], "ot-time-weight"),
    ("reward-bc-schedule-unknown", ["--train.imitation.bc-schedule", "sometimes"], "bc-schedule"),
    ("reward-qfilter-on-ppo", ["--train.imitation.bc-schedule", "qfilter"], "qfilter"),
    ("reward-ot-top-k-more-than-demos", ["--train.imitation.kind", "ot", "--train.imitation.ot-top-k", "100000",
                                         "--demos-episodes", "4"], None),
    ("reward-ot-epsilon-tiny", ["--train.imitation.kind", "ot", "--train.imitation.ot-epsilon", "1e-300"],
     "non-finite"),
    ("reward-ot-scale-huge", ["--train.imitation.kind", "ot", "--train.imitation.ot-scale", "1e300"], "non-finite"),
    ("reward-ot-subtask-on-gail", ["--train.imitation.kind", "ot-subtask"], "ot-subtask"),
    ("reward-relabel-no-goal", ["--train.imitation.relabel-goals", "4"], "goal-conditioned"),
    ("reward-relabel-negative", ["--train.imitation.relabel-goals", "-1"], "relabel-goals"),
    ("reward-relabel-with-ot", ["--train.imitation.kind", "ot", "--train.imitation.relabel-goals", "2"],
     "optimal-transport"),
]:
    probe(_pid, f"`digail train --method gail` (Circle-World) with `{' '.join(_flags)}`", _expect)(
        lambda tmp, f=tuple(_flags): cw_train(tmp, *f))

for _pid, _item, _expect in [
    ("reward-set-kind", "train.imitation.kind=magic", "takes no such value"),
    ("reward-set-prior", "train.imitation.pu_prior=2", "pu-prior"),
    ("reward-set-whole-section", "train.imitation=ot", "is not a setting a sweep may change"),
    ("reward-set-ok-kind", "train.imitation.kind=pu,ot", None),
    ("reward-set-range-top-k", "train.imitation.ot_top_k=0..3", "ranges are searched"),
]:
    probe(_pid, f"`digail sweep --set {_item}`", _expect)(lambda tmp, i=_item: sweep_check((i,)))

# ------------------------------------------------------------------------------------------------ robosuite files
def _rs_copy(tmp: Path, name: str = "stack") -> Path:
    shutil.copy(ROBOSUITE / f"{name}.hdf5", tmp / "rs.hdf5")
    return tmp / "rs.hdf5"


def _rs(edit: Callable[[h5py.File], object], *argv: str, name: str = "stack") -> Callable[[Path], None]:
    def run(tmp: Path) -> None:
        path = _rs_copy(tmp, name)
        with h5py.File(path, "r+") as f:
            edit(f)
        cli(tmp, *argv)

    return run


def _replace(f: h5py.File, key: str, value: np.ndarray) -> None:
    del f[key]
    f[key] = value


IMPORT = ("import", "rs.hdf5", "--out", "out")
for _pid, _what, _edit, _argv, _expect in [
    ("rs-ok", "nothing changed", lambda f: None, IMPORT, None),
    ("rs-actions-missing-in-demo-3", "demo_3's actions removed", lambda f: f.__delitem__("data/demo_3/actions"),
     IMPORT, "demo_3"),
    ("rs-obs-key-missing-in-demo-5", "demo_5's `object` observation removed",
     lambda f: f.__delitem__("data/demo_5/obs/object"), IMPORT, "demo_5"),
    ("rs-actions-wrong-width", "demo_0's actions 3 wide instead of 7",
     lambda f: _replace(f, "data/demo_0/actions", f["data/demo_0/actions"][:, :3]), IMPORT, "actions of shape"),
    ("rs-actions-short", "demo_0 one action short",
     lambda f: _replace(f, "data/demo_0/actions", f["data/demo_0/actions"][:-2]), IMPORT, "demo_0"),
    ("rs-obs-nan", "a NaN in demo_0's eef position",
     lambda f: _replace(f, "data/demo_0/obs/robot0_eef_pos",
                        np.where(np.arange(len(f["data/demo_0/obs/robot0_eef_pos"]))[:, None] == 2, np.nan,
                                 f["data/demo_0/obs/robot0_eef_pos"][...])), IMPORT, "NaN or inf"),
    ("rs-obs-1e300", "demo_0's eef position float64 with a 1e300",
     lambda f: _replace(f, "data/demo_0/obs/robot0_eef_pos",
                        np.where(np.arange(len(f["data/demo_0/obs/robot0_eef_pos"]))[:, None] == 2, 1e300,
                                 f["data/demo_0/obs/robot0_eef_pos"][...].astype(np.float64))), IMPORT, "float32"),
    ("rs-obs-complex", "demo_0's object observation complex",
     lambda f: _replace(f, "data/demo_0/obs/object", f["data/demo_0/obs/object"][...].astype(np.complex64)),
     IMPORT, "complex"),
    ("rs-env-args-not-json", "env_args that is not JSON",
     lambda f: f["data"].attrs.__setitem__("env_args", "{not json"), IMPORT, None),
    ("rs-env-args-deep", "env_args nested 100,000 deep",
     lambda f: f["data"].attrs.__setitem__("env_args", "[" * 100000 + "]" * 100000), IMPORT, None),
    ("rs-data-empty", "no demonstrations under data",
     lambda f: [f["data"].__delitem__(k) for k in list(f["data"].keys())], IMPORT, "rs.hdf5"),
    ("rs-demo-zero-length", "demo_0 with zero steps",
     lambda f: [_replace(f, f"data/demo_0/{k}", f[f"data/demo_0/{k}"][:0])
                for k in ("actions", *(f"obs/{o}" for o in f["data/demo_0/obs"]))], IMPORT, None),
    ("rs-mask-names-missing-demo", "a mask naming demo_999",
     lambda f: f.create_dataset("mask/train", data=np.array([b"demo_0", b"demo_999"])), IMPORT, None),
    ("rs-external-link", "demo_0's actions an external link to another file",
     lambda f: (f.__delitem__("data/demo_0/actions"), f.__setitem__("data/demo_0/actions",
                                                                   h5py.ExternalLink("other.hdf5", "/x"))),
     IMPORT, "link"),
    ("rs-obs-keys-unknown", "nothing changed, `--obs-keys nothing_here`", lambda f: None,
     ("import", "rs.hdf5", "--obs-keys", "nothing_here", "--out", "out"), "nothing_here"),
    ("rs-obs-keys-empty", "nothing changed, `--obs-keys ''`", lambda f: None,
     ("import", "rs.hdf5", "--obs-keys", "", "--out", "out"), "obs"),
    ("rs-import-oracle", "the oracle file imported as demonstrations (it holds MimicGen's signals only)",
     lambda f: None, ("import", "rs.oracle.hdf5", "--out", "out"), "rs.oracle.hdf5"),
    ("rs-import-over-source", "nothing changed, `--out rs.hdf5 --force`", lambda f: None,
     ("import", "rs.hdf5", "--out", "rs.hdf5", "--force"), "rs.hdf5"),
    ("rs-import-into-own-folder", "nothing changed, `--out .`", lambda f: None, ("import", "rs.hdf5", "--out", "."),
     "."),
    ("rs-pickplacecan-ok", "nothing changed", lambda f: None, IMPORT, None),
    ("rs-format-d4rl", "nothing changed, `--format d4rl`", lambda f: None,
     ("import", "rs.hdf5", "--format", "d4rl", "--out", "out"), "rs.hdf5"),
    ("rs-pickplacecan-env-mismatch", "PickPlaceCan's file with `--env digail/FetchPickAndPlace-v4`",
     lambda f: None, ("import", "rs.hdf5", "--env", "digail/FetchPickAndPlace-v4", "--out", "out"), "shape"),
]:
    def _rs_probe(tmp: Path, edit: Callable[[h5py.File], object] = _edit, argv: tuple[str, ...] = tuple(_argv),
                  name: str = "pickplacecan" if "pickplacecan" in _pid else "stack") -> None:
        if "rs.oracle.hdf5" in argv:
            shutil.copy(ROBOSUITE / "stack.oracle.hdf5", tmp / "rs.oracle.hdf5")
        _rs(edit, *argv, name=name)(tmp)

    _task = "PickPlaceCan" if "pickplacecan" in _pid else "Stack"
    probe(_pid, f"`digail {' '.join(_argv)}` on a copy of the robosuite-made {_task} file with {_what}",
          _expect)(_rs_probe)

_VAE_CACHE: list[Path] = []


def _stack_vae(tmp: Path) -> None:
    """A copy of the robosuite Stack file as rs.hdf5 and a small VAE trained on it (made once, copied per probe)."""
    if not _VAE_CACHE:
        import atexit
        import tempfile

        base = Path(tempfile.mkdtemp(prefix="digail-round6-vae-"))
        atexit.register(shutil.rmtree, base, True)
        shutil.copy(ROBOSUITE / "stack.hdf5", base / "rs.hdf5")
        cli(base, "import", "rs.hdf5", "--out", "ds")
        cli(base, "pretrain", "--demos", "ds", "--codes", "2", "--preset", "smoke", "--vae.steps", "20",
            "--vae.init-steps", "0", "--out", "vae")
        _VAE_CACHE.append(base)
    shutil.copy(_VAE_CACHE[0] / "rs.hdf5", tmp / "rs.hdf5")
    shutil.copytree(_VAE_CACHE[0] / "vae", tmp / "stackvae")


for _pid, _argv, _expect in [
    ("rs-export-ok", ["--export", "robomimic", "--names", "reach", "place", "--out", "annotated.hdf5"], None),
    ("rs-export-names-slash", ["--export", "robomimic", "--names", "a/b", "c", "--out", "annotated.hdf5"],
     "--names must be distinct"),
    ("rs-export-names-count", ["--export", "robomimic", "--names", "reach", "--out", "annotated.hdf5"],
     "one name per code"),
    ("rs-export-over-source", ["--export", "robomimic", "--out", "rs.hdf5", "--force"], "rs.hdf5"),
    ("rs-export-csv-into-vae", ["--export", "csv", "--out", "stackvae/model.pt", "--force"], "model.pt"),
]:
    def _rs_export(tmp: Path, argv: tuple[str, ...] = tuple(_argv)) -> None:
        _stack_vae(tmp)
        before = (tmp / "rs.hdf5").read_bytes()
        try:
            cli(tmp, "segment", "stackvae", "--demos", "rs.hdf5", *argv)
        finally:
            assert (tmp / "rs.hdf5").read_bytes() == before, "the source changed"

    probe(_pid, f"`digail segment VAE --demos rs.hdf5 {' '.join(_argv)}` with a VAE of the robosuite-made Stack file",
          _expect)(_rs_export)


# ------------------------------------------------------------------------------------------------ the fifth's classes
for _pid, _value, _expect in [
    ("again-view-stdlib-shutil", "shutil:rmtree", "Python's standard library"),
    ("again-view-importlib", "importlib:import_module", "Python's standard library"),
    ("again-view-dotted-stdlib", "os.path:join", "Python's standard library"),
    ("again-view-fetch-on-metaworld", "digail.envs.fetch:relative_view", None),
    ("again-view-class", "collections:OrderedDict", "Python's standard library"),
    ("again-view-missing-function", "digail.envs.fetch:no_such_view", "has no 'no_such_view'"),
    ("again-view-trailing-colon", "mymod:", "all, relative or module:function"),
    ("again-view-two-colons", "a:b:c", "all, relative or module:function"),
]:
    probe(_pid, f"`digail train --demos {MW_DEMOS} --train.disc-obs {_value}`", _expect)(
        lambda tmp, v=_value: mw_train(tmp, "--train.disc-obs", v))


for _pid, _text, _expect in [
    ("again-spec-disc-obs-os", f'envs = ["{CW}"]\n[set]\n"train.disc_obs" = "os:system"\n', "standard library"),
    ("again-spec-grid-disc-obs", f'[[grid]]\nenvs = ["{CW}"]\nset = {{ "train.disc_obs" = ["all", "sys:exit"] }}\n',
     "standard library"),
]:
    probe(_pid, f"`digail sweep --spec spec.toml` whose spec sets {_text.split(chr(10))[-2]}", _expect)(
        lambda tmp, t=_text: sweep_check(spec=t, tmp=tmp))


@probe("again-mw-run-folder-module", "`digail report run` where a Meta-World run's config.json names env "
       "`evil6b:MW-v0` and evil6b.py is in the current folder", None)
def _mw_run_module(tmp: Path) -> None:
    shutil.copytree(RUN, tmp / "run")
    config = json.loads((tmp / "run" / "config.json").read_text())
    config["env_id"] = "evil6b:MW-v0"
    (tmp / "run" / "config.json").write_text(json.dumps(config))
    plant(tmp, "evil6b")
    cli(tmp, "report", "run")


@probe("again-resume-env-module", "`digail train --resume run` where config.json's env is `evil6c:MW-v0`",
       "pass --env evil6c:MW-v0 to allow it")
def _mw_resume(tmp: Path) -> None:
    plant(tmp, "evil6c")
    (tmp / "run").mkdir()
    (tmp / "run" / "config.json").write_text(json.dumps({
        "kind": "gail", "env_id": "evil6c:MW-v0", "seed": 0,
        "args": {"env": "evil6c:MW-v0", "demos": MW_DEMOS, "seed": 0, "method": "gail", "preset": "smoke"}}))
    cli(tmp, "train", "--resume", "run")


# ------------------------------------------------------------------------------------------------ the test
@pytest.mark.parametrize("p", PROBES, ids=[p.id for p in PROBES])
def test_probe(p: Probe, tmp_path: Path) -> None:
    sentence = outcome(p, tmp_path)
    assert_answer(p, sentence)
    assert ran(tmp_path) == [], f"{p.id} ran a module a data file named"
    if p.expect is not None:
        for out in ("out", "run-new", "vae"):
            assert not (tmp_path / out).exists(), f"{p.id} wrote {out}"


def test_at_least_a_hundred_probes() -> None:
    assert len(PROBES) >= 100, len(PROBES)


def test_the_reliability_page_lists_every_probe() -> None:
    """docs/reference/errors.md publishes these probes in the sixth round's section: one row each."""
    page = (REPO / "docs" / "reference" / "errors.md").read_text()
    section = page.split("## Probes, sixth round", 1)[1].split("\n## ", 1)[0]
    rows = [ln for ln in section.splitlines() if ln.startswith("| ") and not ln.startswith(("| tried", "| ---"))]
    assert len(rows) == len(PROBES)
    missing = [p.id for p in PROBES if f"| {p.what.replace('|', chr(92) + '|')} |" not in section]
    assert not missing, f"probes without a row in the reliability page: {missing}"
