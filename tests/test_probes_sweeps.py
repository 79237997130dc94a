"""Failure-path probes of `digail sweep`: what an override may set, spec files, and the values of the
sweep's own options, checked before Ray starts or anything is written. The probes, with what each gets, are the
reliability page's section of the same name (docs/reference/errors.md).
"""

from __future__ import annotations

import os
import shutil
import sys
import types
from pathlib import Path

import pytest
from probe_kit import (
    CW,
    ROOT,
    Probe,
    ProbeTable,
    assert_published,
    check_probe,
    cli,
    sweep_check,
)

from digail.fsio import MARKER, digail_made

PROBES = ProbeTable()
probe = PROBES.add


# ------------------------------------------------------------------------------------------------ sweep overrides
NOT_A_SETTING = "is not a setting a sweep may change"
for _key in ("pretrain.out", "pretrain.force", "pretrain.resume", "pretrain.demos", "pretrain.device", "pretrain.seed",
             "pretrain.preset", "pretrain.demos_episodes", "train.out", "train.resume", "train.vae", "train.demos",
             "train.device", "train.force", "train.method", "train.ppo", "train.sac", "evaluate.run", "evaluate.out",
             "segment.demos", "segment.run", "demos.path", "demos.dataset", "vae.codes.x"):
    probe(f"set-{_key}", f"`digail sweep --set {_key}=...`", NOT_A_SETTING)(
        lambda tmp, k=_key: sweep_check((f"{k}=x",)))

for _pid, _item, _expect in [
    ("set-upper", "Train.iterations=3", "names no stage option"),
    ("set-double-dot", "train..iterations=3", NOT_A_SETTING),
    ("set-below-leaf", "train.iterations.x=3", NOT_A_SETTING),
    ("set-flag-value", "train.bonus_weight=--out", "a value may not start with '-'"),
    ("set-flag-in-tuple", "train.hidden=64 --force", "a value may not start with '-'"),
    ("set-short-flag", "train.imitation.logits_to_reward=-h", "a value may not start with '-'"),
    ("set-negative-number", "train.bonus_weight=-1", None),
    ("set-equals-in-value", "train.imitation.logits_to_reward=a=b", "train.imitation.logits_to_reward=a=b"),
    ("set-zero-episodes", "demos.episodes=0", "--demos-episodes must be at least 1"),
    ("set-nan", "train.bonus_weight=nan", "train.bonus_weight"),
    ("set-no-value", "train.iterations", "write KEY=VALUE"),
    ("set-ok-ppo-lr", "train.ppo.lr=1e-4", None),
    ("set-ok-kl", "vae.kl_weight=0.5", None),
    ("set-ok-subsample", "demos.subsample=2", None),
    ("set-ok-episodes", "demos.episodes=2", None),
    ("set-ok-codes", "pretrain.codes=3", None),
    ("set-vae-codes", "vae.codes=3", NOT_A_SETTING),
    ("set-ok-eval-episodes", "evaluate.episodes=5", None),
    ("set-ok-label-map", "segment.label_map=0 1", None),
    ("set-ok-sac-buffer", "train.sac.buffer_size=1000", None),
    ("set-ok-grid", "train.bonus_weight=0.01,0.1", None),
]:
    probe(_pid, f"`digail sweep --set {_item}`", _expect)(lambda tmp, i=_item: sweep_check((i,)))

for _pid, _text, _expect in [
    ("spec-set-out", f'envs = ["{CW}"]\n[set]\n"pretrain.out" = "/tmp"\n', NOT_A_SETTING),
    ("spec-grid-set-run", f'[[grid]]\nenvs = ["{CW}"]\nset = {{ "evaluate.run" = "x" }}\n', NOT_A_SETTING),
    ("spec-inner-list-flag", f'envs = ["{CW}"]\nset = {{ "train.hidden" = [[64, "--force"]] }}\n',
     "a value may not start with '-'"),
    ("spec-range-on-out", f'envs = ["{CW}"]\nset = {{ "train.out" = {{ low = 1, high = 2 }} }}\n', NOT_A_SETTING),
    ("spec-nested-list", f'envs = ["{CW}"]\nset = {{ "train.hidden" = [[[64]]] }}\n', "nests a list in a list"),
    ("spec-ok", f'envs = ["{CW}"]\nmethods = ["vae"]\nset = {{ "vae.kl_weight" = [0.5, 1.0] }}\n', None),
]:
    probe(_pid, f"a sweep spec: `{_text.splitlines()[-1]}`", _expect)(lambda tmp, t=_text: sweep_check(spec=t, tmp=tmp))


for _pid, _item, _expect in [
    ("reward-set-kind", "train.imitation.reward=magic", "takes no such value"),
    ("reward-set-prior", "train.imitation.pu_prior=2", "pu-prior"),
    ("reward-set-whole-section", "train.imitation=ot", "is not a setting a sweep may change"),
    ("reward-set-ok-kind", "train.imitation.reward=pu,ot", None),
    ("reward-set-range-top-k", "train.imitation.ot_top_k=0..3", "ranges are searched"),
]:
    probe(_pid, f"`digail sweep --set {_item}`", _expect)(lambda tmp, i=_item: sweep_check((i,)))



# ------------------------------------------------------------------------------------------------ the sweep's options
for _pid, _argv, _expect in [
    ("options-num-cpus-0", ["--num-cpus", "0"], "--num-cpus must be at least 1"),
    ("options-num-cpus-negative", ["--num-cpus", "-2"], "--num-cpus must be at least 1"),
]:
    probe(_pid, f"`digail sweep --envs {CW} {' '.join(_argv)} --out sweep`", _expect)(
        lambda tmp, a=tuple(_argv): cli(tmp, "sweep", "--envs", CW, *a, "--out", "sweep"))


def _sweep_targets(tmp: Path) -> None:
    """A folder of the user's, a link to it and a FIFO, where a sweep folder could be aimed."""
    (tmp / "mine").mkdir()
    (tmp / "mine" / "results.md").write_text("a user's notes\n")
    (tmp / "link").symlink_to(tmp / "mine")
    os.mkfifo(tmp / "fifo")


for _pid, _out, _what, _expect in [
    ("options-out-users-folder", "mine", "a folder of the user's", "is a folder digail did not make"),
    ("options-out-link", "link", "a link to a folder of the user's", "is a symbolic link"),
    ("options-out-fifo", "fifo", "a FIFO", "is a file, not a folder"),
]:
    probe(_pid, f"`digail sweep --envs {CW} --out {_out}`: {_what}", _expect, setup=_sweep_targets)(
        lambda tmp, o=_out: cli(tmp, "sweep", "--envs", CW, "--out", o))


# ---------------------------------------------------------------------------------------- tests beyond the probes
def _stale(sweep: Path) -> list[Path]:
    return sorted(sweep.rglob(".vae_s0.*"))


def test_a_resumed_sweep_stage_removes_what_a_killed_attempt_left(tmp_path):
    from digail.sweep.engine import run_job
    from digail.sweep.plan import Job, Stage

    sweep = tmp_path / "sweep"
    left = sweep / "env" / ".vae_s0.tmp-abc123"
    (left / "figures").mkdir(parents=True)
    (left / "losses.csv").write_text("epoch,loss\n")
    (sweep / "env" / ".vae_s0.old-xyz").mkdir()
    (sweep / "env" / ".other.tmp-1").mkdir()  # another folder's: not this stage's to remove
    job = Job(id="env/pretrain_s0", kind="vae", env=CW, method="pretrain", seed=0, run="env/vae_s0",
              stages=(Stage("pretrain", ("pretrain", "--help"), run="env/vae_s0"),))
    from digail.sweep.engine import job_to_dict

    run_job(job_to_dict(job), str(sweep))
    assert _stale(sweep) == [] and (sweep / "env" / ".other.tmp-1").is_dir()


def test_an_interrupted_sweep_removes_its_killed_stages_temporaries(tmp_path, monkeypatch):
    from digail.sweep import engine
    from digail.sweep.plan import Job, Stage

    sweep = tmp_path / "sweep"
    job = Job(id="env/pretrain_s0", kind="vae", env=CW, method="pretrain", seed=0, run="env/vae_s0",
              stages=(Stage("pretrain", ("pretrain",), run="env/vae_s0"),))
    cancelled = []

    class Remote:
        def options(self, **_: object) -> Remote:
            return self

        def remote(self, *_: object) -> str:
            # the stage starts writing its VAE atomically, then the user presses Ctrl-C
            (sweep / "env" / ".vae_s0.tmp-k1ll3d").mkdir(parents=True)
            return "ref"

    def wait(*_: object, **__: object) -> None:
        raise KeyboardInterrupt

    fake = types.SimpleNamespace(remote=lambda fn: Remote(), cluster_resources=lambda: {"CPU": 2.0}, wait=wait,
                                 cancel=lambda ref, force: cancelled.append(ref), is_initialized=lambda: False)
    monkeypatch.setitem(sys.modules, "ray", fake)
    with pytest.raises(KeyboardInterrupt):
        engine.execute([job], sweep, shared_fs=True, log=lambda _: None)
    assert cancelled == ["ref"] and _stale(sweep) == []


def test_sweep_folders_carry_the_marker(tmp_path):
    from digail.sweep import Grid, SweepSpec, plan, save_plan

    spec = SweepSpec(grids=(Grid(envs=(CW,), methods=("vae",), preset="smoke"),))
    save_plan(tmp_path / "sweep", spec, plan(spec))
    assert (tmp_path / "sweep" / MARKER).is_file() and digail_made(tmp_path / "sweep")
    shutil.rmtree(tmp_path / "sweep")


@pytest.mark.parametrize("spec_file", sorted((ROOT / "benchmarks" / "sweeps").glob("*.toml")), ids=lambda p: p.name)
def test_every_shipped_sweep_spec_passes_the_checks_before_ray(spec_file):
    """The allow-list keeps every override the published sweeps use; `demos.*` keys are checked against both the
    VAE's and the training's command (they once crashed the check with a KeyError)."""
    from digail.commands.sweep import check_spec
    from digail.sweep.plan import plan
    from digail.sweep.spec import build_spec

    spec = build_spec(spec_file=spec_file)
    check_spec(spec, plan(spec) if spec.search is None else [])


# ------------------------------------------------------------------------------------------------ the probes
@pytest.mark.parametrize("p", PROBES, ids=[p.id for p in PROBES])
def test_probe(p: Probe, tmp_path: Path, request: pytest.FixtureRequest) -> None:
    check_probe(p, tmp_path, request.getfixturevalue("base") if p.on_base else None)


def test_the_reliability_page_lists_every_probe() -> None:
    assert_published(PROBES, "Probes: sweeps")
