"""`digail sweep`: planning (no Ray), and a local-Ray sweep on SMOKE settings with a trial whose Ray worker is killed
mid-training (it resumes from its checkpoint) and one that fails on purpose (reported, the others finish)."""

from __future__ import annotations

import importlib.util
import json
import os
import signal
import threading
import time
from pathlib import Path

import pytest

from digail.commands.flags import renamed
from digail.errors import UserError
from digail.sweep import load_plan, run_sweep, summarize_sweep
from digail.sweep.plan import plan
from digail.sweep.spec import build_spec, load_spec, parse_set, spec_from_dict

ROOT = Path(__file__).resolve().parents[1]
CW, FR = "digail/CircleWorld-v0", "digail/FourRooms-v0"


# ------------------------------------------------------------------------------------------- planning
def test_plan_shares_vaes_names_runs_and_writes_cli_flags():
    spec = build_spec(envs=(CW,), methods=("vae", "digail", "gail", "digail-l2"), seeds=(0, 1), preset="smoke",
                      episodes=5, sets=("train.bonus_weight=0.1,0.2", "vae.decoder_obs=0 26",
                                        "train.ppo.anneal_lr=false"))
    jobs = {j.id: j for j in plan(spec)}
    vaes = [j for j in jobs.values() if j.kind == "vae"]
    assert [j.id for j in vaes] == ["digail-CircleWorld-v0/pretrain_s0", "digail-CircleWorld-v0/pretrain_s1"]
    assert vaes[0].stages[0].argv == ("pretrain", "--demos", "digail/circleworld/expert-v0", "--seed", "0", "--out",
                                      "digail-CircleWorld-v0/vae_s0", "--force", "--preset", "smoke",
                                      "--vae.decoder-obs", "0", "26")
    # the VAE baseline ignores train.* overrides (one trial per seed); gail uses no VAE; -l2 gets --train.bc-weight
    assert "digail-CircleWorld-v0/vae_s0" in jobs and jobs["digail-CircleWorld-v0/vae_s0"].stages[0].argv == (
        "evaluate", "digail-CircleWorld-v0/vae_s0", "--episodes", "5")
    dig = jobs["digail-CircleWorld-v0/digail_s1__train.bonus_weight=0.2"]
    assert dig.deps == ("digail-CircleWorld-v0/pretrain_s1",) and dig.label == "digail [train.bonus_weight=0.2]"
    train = dig.stages[0]
    assert [s.name for s in dig.stages] == ["train", "evaluate", "segment"]
    assert train.argv[:2] == ("train", "--method") and "--train.ppo.no-anneal-lr" in train.argv
    assert train.argv[train.argv.index("--train.bonus-weight") + 1] == "0.2"
    assert train.resume == ("train", "--resume", dig.run)
    gail = jobs["digail-CircleWorld-v0/gail_s0__train.bonus_weight=0.1"]
    assert gail.deps == () and "--vae" not in gail.stages[0].argv
    l2 = jobs["digail-CircleWorld-v0/digail-l2_s0__train.bonus_weight=0.1"].stages[0].argv
    assert l2[l2.index("--train.bc-weight") + 1] == "1.0"
    assert len(jobs) == 2 + 2 * (1 + 2 * 3)


def test_gpu_trials_run_their_vae_and_trainer_on_cuda():
    spec = build_spec(envs=(CW,), methods=("vae", "digail", "gail"), preset="smoke", gpus_per_trial=0.5)
    stages = [s for j in plan(spec) for s in j.stages]
    heavy = [s for s in stages if s.name in ("pretrain", "train")]
    assert len(heavy) == 3 and all(s.argv[s.argv.index("--device") + 1] == "cuda" for s in heavy)
    assert not any("--device" in s.argv for s in stages if s.name not in ("pretrain", "train"))
    cpu_only = [s for j in plan(build_spec(envs=(CW,), preset="smoke")) for s in j.stages]
    assert not any("--device" in s.argv for s in cpu_only)  # CPU sweeps keep their commands (and resume)


def test_packs_carry_folders_and_replace_them_whole(tmp_path):
    from digail.sweep.transfer import pack, unpack

    src, dst = tmp_path / "src", tmp_path / "dst"
    (src / "env" / "run").mkdir(parents=True)
    (src / "env" / "run" / "checkpoint.pt").write_bytes(b"weights")
    (src / "trials").mkdir()
    (src / "trials" / "run.json").write_text("{}")
    (dst / "env" / "run").mkdir(parents=True)
    (dst / "env" / "run" / "stale.txt").write_text("from an earlier attempt")
    (dst / "env" / "other").mkdir()
    got = unpack(pack(src, ["env/run", "trials/run.json", "logs/missing.log"]), dst)
    assert got == ["env/run", "trials/run.json"]
    assert (dst / "env" / "run" / "checkpoint.pt").read_bytes() == b"weights"
    assert not (dst / "env" / "run" / "stale.txt").exists() and (dst / "env" / "other").is_dir()
    assert sorted(p.name for p in dst.iterdir()) == ["env", "trials"]  # no staging folder left
    with pytest.raises(ValueError, match="leaves the sweep folder"):
        pack(src, ["../outside"])


def test_bad_sweeps_are_user_errors(tmp_path):
    with pytest.raises(UserError, match="unknown method"):
        build_spec(envs=(CW,), methods=("ppo",))
    with pytest.raises(UserError, match="names no stage option"):
        parse_set(["bonus_weight=0.1"])
    with pytest.raises(UserError, match="ranges are searched"):
        plan(build_spec(envs=(CW,), sets=("train.bonus_weight=0.001..0.1:log",)))
    with pytest.raises(UserError, match="no sweep spec"):
        load_spec(tmp_path / "missing.toml")
    with pytest.raises(UserError, match="nothing to sweep"):
        build_spec()


def _harness(name: str):
    spec = importlib.util.spec_from_file_location(f"bench_{name}", ROOT / "benchmarks" / f"{name}.py")
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def _train_flags(argv: tuple[str, ...]) -> set[str]:
    """A train command's settings as 'flag value' strings, without the folders (which each harness names); a flag
    renamed since a published command ran is read under its new name."""
    out, skip = set(), {"--out", "--vae", "--force", "--demos"}
    args = list(argv[1:])
    i = 0
    while i < len(args):
        if args[i] in skip:
            i += 1 if args[i] == "--force" else 2
            continue
        value = args[i + 1] if i + 1 < len(args) and not args[i + 1].startswith("--") else ""
        out.add(f"{renamed(args[i]) or args[i]} {value}".strip())
        i += 2 if value else 1
    return out


def test_table1_spec_expresses_the_published_trials():
    """sweeps/table1.toml plans the trials the published Table 1 ran (benchmarks/results/table1/table1.json records
    every trial's commands): the same env, method and seed cells, the same training flags, 300 evaluation
    episodes."""
    published = json.loads((ROOT / "benchmarks" / "results" / "table1" / "table1.json").read_text())
    recorded = {f"{row['env_id']}:{method}:{r['seed']}": r for row in published.values()
                for method, cell in row["methods"].items() for r in cell["seeds"]}
    jobs = [j for j in plan(load_spec(ROOT / "benchmarks" / "sweeps" / "table1.toml")) if j.kind == "trial"]
    planned = {f"{j.env}:{j.method}:{j.seed}": j for j in jobs}
    assert sorted(planned) == sorted(recorded)
    for key, job in planned.items():
        [evaluate] = [s for s in job.stages if s.name == "evaluate"]
        assert evaluate.argv == ("evaluate", job.run, "--episodes", "300")
        assert recorded[key]["episodes"] == 300
        if job.method == "vae":
            continue
        [train] = [c for c in recorded[key]["commands"] if c.startswith("digail train --method")][-1:]
        assert _train_flags(job.stages[0].argv) == _train_flags(tuple(train.split()[1:])), key


def test_table1_generator_builds_the_published_rows_from_a_sweep(tmp_path):
    """benchmarks/table1.py reads a sweep's results.json and its runs' learning curves into table1.json's rows
    (the steps at which training first reached 0.9, the target, the medians) and the Markdown table."""
    table1 = _harness("table1")
    seeds = {}
    for seed, (ret, curve) in enumerate([(3400.0, [(0, 0.95), (4096, 0.5), (8192, 0.92)]),
                                         (3000.0, [(0, 0.2), (4096, 0.91)]), (3500.0, [(0, 0.1)])]):
        run = tmp_path / "Hopper-v5" / f"digail_s{seed}"
        run.mkdir(parents=True)
        (run / "metrics.csv").write_text("step,eval/normalized_return\n" + "".join(f"{s},{v}\n" for s, v in curve))
        seeds[str(seed)] = {"seed": seed, "run": f"Hopper-v5/digail_s{seed}", "status": "done",
                            "metrics": {"mean_return": ret, "std_return": 10.0, "normalized_return": ret / 3500.0,
                                        "expert/mean_return": 3500.0, "expert/std_return": 5.0, "episodes": 300},
                            "env_steps": 12288, "wall_s": 60.0, "commands": [f"digail train --seed {seed}"]}
    results = {"name": "table1", "table": {"Hopper-v5": {"digail": {"seeds": seeds}}}}
    t = table1.table(results, tmp_path)
    cell = t["hopper"]["methods"]["digail"]
    assert [(r["steps_to_0.9"], r["steps_to_0.9_after_step_0"]) for r in cell["seeds"]] == \
        [(0.0, 8192.0), (4096.0, 4096.0), (None, None)]
    assert [r["meets_target"] for r in cell["seeds"]] == [True, False, True]
    assert cell["median_mean_return"] == 3400.0 and cell["complete"]
    assert list(t["hopper"]["paper"]["digail"]) == [3662.1, 21.7]
    assert set(t) == {"hopper", "pendulum", "invertedpendulum", "walker2d"}
    [row] = [line for line in table1.markdown(t).splitlines() if line.startswith("| Hopper-v5")]
    assert row == ("| Hopper-v5 | Directed-Info GAIL | 3662.1 +- 21.7 | 3400.0 +- 10.0 | 0.971 / 0.857 / 1.000 | "
                   "0.971 | 0 (init), 8k / 4k / never | 3 of 3 |")


# What the README's Four Rooms and Circle-World tables ran (the former benchmarks/results.py): the specs must keep it.
README_TABLES = {
    "results-fourrooms": dict(env="digail/FourRooms-v0", gail=False, compose=False),
    "results-circleworld": dict(env="digail/CircleWorld-v0", gail=True, compose=True),
}


def test_results_specs_express_the_readme_tables():
    for spec_name, info in README_TABLES.items():
        jobs = [j for j in plan(load_spec(ROOT / "benchmarks" / "sweeps" / f"{spec_name}.toml"))
                if j.kind == "trial"]
        methods = {j.method for j in jobs}
        assert methods == ({"vae", "digail", "digail-l2", "gail"} if info["gail"] else {"vae", "digail"})
        assert {j.seed for j in jobs} == {0, 1, 2} and {j.env for j in jobs} == {info["env"]}
        for job in jobs:
            assert any(s.argv[-1] == "300" for s in job.stages if s.name == "evaluate")
            assert any(s.name == "compose" for s in job.stages) == (info["compose"] and job.method in ("vae", "digail"))
            if job.method == "gail":
                assert {"--train.ppo.policy-lr 0.0003", "--train.anchor-weight 0.0"} <= _train_flags(job.stages[0].argv)
            if job.method == "digail-l2":
                assert "--train.bc-weight 100.0" in _train_flags(job.stages[0].argv)


# --------------------------------------------------------------------------------------- a local Ray
FAULT_SPEC = """
name = "faults"
preset = "smoke"
episodes = 3
retries = 1

[[grid]]     # its Ray worker is killed mid-training: the retry continues with `digail train --resume`
envs = ["digail/CircleWorld-v0"]
methods = ["digail"]
seeds = [0]
set = { "train.iterations" = 60 }

[[grid]]
envs = ["digail/CircleWorld-v0"]
methods = ["vae"]
seeds = [1]

[[grid]]
envs = ["digail/FourRooms-v0"]
methods = ["vae"]
seeds = [0]

[[grid]]     # fails on purpose: no such reward, on every attempt
envs = ["digail/FourRooms-v0"]
methods = ["gail"]
seeds = [1]
set = { "train.imitation.logits_to_reward" = "bogus" }
"""


@pytest.fixture(scope="module")
def ray_local():
    """A local Ray as `digail sweep` starts it: on 127.0.0.1, its session folder removed at the end."""
    ray = pytest.importorskip("ray")
    from digail.sweep import start_ray, stop_ray

    os.environ.setdefault("MUJOCO_GL", "egl")
    session = start_ray(num_cpus=2)
    yield ray
    stop_ray(session)
    assert session.folder is not None and not Path(session.folder).exists()


def _procs() -> list[tuple[int, int, list[str], str]]:
    """(pid, parent pid, argv, cwd) of this user's processes."""
    out = []
    for entry in Path("/proc").iterdir():
        if not entry.name.isdigit():
            continue
        try:
            argv = (entry / "cmdline").read_bytes().decode().split("\0")
            ppid = int((entry / "stat").read_text().rsplit(")", 1)[1].split()[1])
            cwd = os.readlink(entry / "cwd")
        except (OSError, ValueError, IndexError):
            continue
        out.append((int(entry.name), ppid, argv, cwd))
    return out


def _kill_worker_mid_training(sweep: Path, run: str, done: threading.Event, killed: list[int]) -> None:
    """Once `run` has a checkpoint and is still training, SIGKILL the Ray worker running it (a lost worker)."""
    while not done.is_set():
        if (sweep / run / "checkpoint.pt").exists():
            for pid, ppid, argv, cwd in _procs():
                if "digail.cli" in argv and "train" in argv and run in argv and cwd == str(sweep):
                    os.kill(pid, signal.SIGSTOP)  # frozen first: the stage cannot finish while its worker dies
                    os.kill(ppid, signal.SIGKILL)
                    killed += [ppid, pid]
                    return
        time.sleep(0.02)


@pytest.mark.slow  # about 3 minutes of Ray on 2 cores: CI runs it with `make test-slow`
def test_local_sweep_survives_a_killed_worker_and_reports_a_failure(ray_local, tmp_path, capsys):
    sweep = (tmp_path / "sweep").resolve()
    spec = spec_from_dict(__import__("tomllib").loads(FAULT_SPEC))
    killed: list[int] = []
    done = threading.Event()
    run = "digail-CircleWorld-v0/digail_s0"
    killer = threading.Thread(target=_kill_worker_mid_training, args=(sweep, run, done, killed), daemon=True)
    killer.start()
    try:
        result = run_sweep(spec, sweep, summary_every=5.0)
    finally:
        done.set()
    out = capsys.readouterr().out
    assert killed, "the training finished before it could be killed"
    time.sleep(0.5)
    assert not Path(f"/proc/{killed[1]}").exists(), "the stage outlived its Ray worker"

    # the killed trial was retried and continued from its checkpoint to the end of its budget
    state = json.loads((sweep / "trials" / "digail-CircleWorld-v0__digail_s0.json").read_text())
    assert state["status"] == "done" and state["attempts"] == 2
    assert f"digail train --resume {run}" in state["commands"]
    log = (sweep / "logs" / "digail-CircleWorld-v0__digail_s0.log").read_text()
    assert "resuming" in log and "/60" in log
    rows = (sweep / run / "metrics.csv").read_text().strip().splitlines()
    assert float(rows[-1].split(",")[1]) == 60  # iteration column

    # the bad trial: tried twice, reported with its error, the others finished
    assert result["done"] == 3 and result["trials"] == 4
    [failed] = result["failed"]
    assert failed["job"] == "digail-FourRooms-v0/gail_s1" and "bogus" in failed["error"]
    assert "[sweep] retry  digail-FourRooms-v0/gail_s1" in out and "failed digail-FourRooms-v0/gail_s1" in out
    assert "[sweep] run    digail-CircleWorld-v0/digail_s0" in out and "env steps/s" in out
    assert "train -> evaluate -> segment (resuming train)" in out

    # the table is the trials' own eval.json, seed by seed
    for env, rows_ in result["table"].items():
        for row in rows_.values():
            for rec in row["seeds"].values():
                if rec["status"] != "done":
                    continue
                ev = json.loads((sweep / rec["run"] / "eval.json").read_text())
                assert ev["episodes"] == 3
                for key in ("mean_return", "std_return"):
                    assert rec["metrics"][key] == pytest.approx(ev[key]), (env, key)
                assert row["median"]["mean_return"] == pytest.approx(ev["mean_return"])  # one seed per row
                assert rec["commands"] and rec["commands"][0].startswith("digail ")
    dig = result["table"][CW]["digail"]["seeds"]["0"]
    assert dig["env_steps"] == 60 * 64 and dig["commands"][0].startswith("digail pretrain")
    assert "seg/accuracy" in dig["metrics"]
    md = (sweep / "results.md").read_text()
    assert "## digail/CircleWorld-v0" in md and "| digail | 1/1 |" in md and "gail_s1" in md

    # a second call skips every finished trial and only retries the failed one
    before = {p.name: p.read_text() for p in (sweep / "trials").glob("*.json") if "gail_s1" not in p.name}
    run_sweep(spec.with_flags(retries=0), sweep, summary_every=5.0)
    out = capsys.readouterr().out
    assert "7 jobs: 6 finished before, 1 to run" in out
    assert before == {p.name: p.read_text() for p in (sweep / "trials").glob("*.json") if "gail_s1" not in p.name}

    # --summarize rebuilds the same tables from the folder alone
    again = summarize_sweep(sweep)
    assert again["table"][CW]["digail"]["median"] == result["table"][CW]["digail"]["median"]
    assert len(load_plan(sweep)[1]) == 7


def test_documented_sweep_commands_parse_and_plan():
    """Every `digail sweep` line of the README and the docs parses and plans (nothing runs)."""
    import shlex

    import tyro

    from digail.commands.sweep import SweepArgs

    pages = [ROOT / "README.md", *sorted((ROOT / "docs").rglob("*.md"))]
    text = "\n".join(page.read_text() for page in pages).replace("\\\n", " ")
    lines = [ln.split("#", 1)[0] for ln in text.splitlines() if ln.strip().startswith("digail sweep")]
    assert len(lines) >= 6
    for line in lines:
        words = shlex.split(line)
        # the sweep's own words end where the shell's begin (`&&`, `&`, `;`, `|`)
        ends = [i for i, w in enumerate(words) if w in ("&&", "||", "&", ";", "|")]
        args = tyro.cli(SweepArgs, args=words[2:ends[0] if ends else None])
        if args.summarize is not None:
            continue
        spec = build_spec(envs=args.envs, methods=args.methods, seeds=args.seeds, preset=args.preset,
                          episodes=args.episodes, sets=args.set,
                          spec_file=ROOT / args.spec if args.spec else None, search=args.search,
                          trials=args.trials, metric=args.metric)
        if spec.search is None:
            assert plan(spec), line


def test_search_space_and_sample_runs_named_after_their_values():
    pytest.importorskip("ray")
    from ray import tune

    from digail.sweep.search import check_metric, sample_jobs, search_space, tune_space

    spec = build_spec(envs=(FR,), methods=("digail",), seeds=(0, 1), preset="smoke",
                      sets=("train.bonus_weight=0.001..0.1:log", "train.ppo.epochs=1..4",
                            "train.imitation.logits_to_reward=positive,negative"),
                      search="optuna", trials=4, metric="eval/success_rate")
    space = search_space(spec)
    assert str(space["train.bonus_weight"]) == "0.001..0.1:log" and space["train.ppo.epochs"].integer
    assert space["train.imitation.logits_to_reward"] == ("positive", "negative")
    domains = tune_space(space)
    assert isinstance(domains["train.bonus_weight"], tune.search.sample.Float)
    assert isinstance(domains["train.ppo.epochs"], tune.search.sample.Integer)
    jobs = sample_jobs(spec, {"train.bonus_weight": 0.0123, "train.ppo.epochs": 2,
                              "train.imitation.logits_to_reward": "negative"}, tuple(sorted(space)))
    runs = sorted(j.run for j in jobs if j.kind == "trial")
    assert runs[0] == ("digail-FourRooms-v0/digail_s0__train.bonus_weight=0.0123"
                       "__train.imitation.logits_to_reward=negative__train.ppo.epochs=2")
    assert sorted(j.run for j in jobs if j.kind == "vae") == ["digail-FourRooms-v0/vae_s0",
                                                              "digail-FourRooms-v0/vae_s1"]
    assert check_metric("seg/nmi") == ("segmentation.json", "nmi")
    with pytest.raises(UserError, match="metric"):
        check_metric("normalized_return")


def test_table2_harness_tabulates_a_sweep_and_judges_the_targets():
    """benchmarks/table2.py on a sweep's results.json: per-seed rates, medians, the issue's targets, the table."""
    table2 = _harness("table2")

    def seed(s: int, success: float, dense: float, status: str = "done") -> dict:
        metrics = {"mean_return": dense, "std_return": 1.0, "sparse_return": 10 * dense, "success_rate": success,
                   "grasp_rate": min(1.0, success + 0.1), "lift_rate": 0.5, "normalized_return": 1.0,
                   "episodes": 100}
        return {"seed": s, "run": f"fetch/m_s{s}", "status": status, "metrics": metrics, "env_steps": 204800,
                "wall_s": 60.0, "commands": ["digail train ..."]}

    results = {"name": "table2", "table": {table2.ENV: {
        "digail-l2": {"seeds": {"0": seed(0, 0.9, -6.0), "1": seed(1, 0.4, -8.0), "2": seed(2, 0.7, -7.0)}},
        "gail-l2": {"seeds": {"0": seed(0, 0.8, -6.5), "1": seed(1, 0.1, -9.0), "2": seed(2, 0.0, -1.0, "failed")}},
    }}}
    t = table2.table(results)
    best, base = t["methods"]["digail-l2"], t["methods"]["gail-l2"]
    assert best["median_success_rate"] == 0.7 and best["median_mean_return"] == -7.0 and best["complete"]
    assert [r["seed"] for r in base["seeds"]] == [0, 1] and not base["complete"]  # the failed seed is left out
    assert base["median_success_rate"] == pytest.approx(0.45)
    assert t["targets"] == {"digail_l2_success_median_at_least_0.5": True, "digail_l2_success_at_least_gail_l2": True,
                            "digail_l2_dense_better_than_paper": True, "complete": False}
    md = table2.markdown(t)
    assert "| Directed-Info GAIL + L2 | -9.47 | -7.00 +- 1.00 | 0.90 / 0.40 / 0.70 |" in md
    assert "| GAIL + L2 | -12.05 |" in md and "2 of 3" in md and "| VAE |" not in md
