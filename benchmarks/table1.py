"""The paper's Table 1 (continuous control): VAE, GAIL and Directed-Info GAIL (+ L2) on four envs, 3 seeds.

The same trials as a sweep spec, on Ray (local or a cluster): `digail sweep --spec benchmarks/sweeps/table1.toml
--out runs/sweeps/table1` (tests/test_sweep.py checks that the spec's commands are this harness's).

    python benchmarks/table1.py run hopper digail 0      one trial: pre-train (shared) -> train -> evaluate
    python benchmarks/table1.py queue hopper:digail:0 walker2d:gail:1 ...   trials in turn (one per core)
    python benchmarks/table1.py summarize                -> benchmarks/results/table1.json
    python benchmarks/table1.py plan                     every trial of the table, as queue arguments
    python benchmarks/table1.py progress                 -> benchmarks/results/table1_progress.json: the
                                                         eval/* learning curve of every started trial so far
    python benchmarks/table1.py run hopper vae-k8 0      the appendix's K = 8 VAE on Hopper (for its PCA figure)
    python benchmarks/table1.py markdown                 the results table from table1.json, the paper's beside ours
    python benchmarks/table1.py readme                   the same table into docs/results.md (between its markers)
    python benchmarks/table1.py publish                  the median seed's run folder per env and method (model,
                                                         config, eval, curves, figures) -> benchmarks/results/runs/
    python benchmarks/table1.py figures                  -> benchmarks/results/figures/table1/ (learning curves,
                                                         code strips, Pendulum code map, K = 8 PCA) and
                                                         benchmarks/results/table1_codes.json (code-gait agreement)

Every stage is exactly what a user would type (printed as it runs):
    digail pretrain --demos D --seed S --out R/vae_sS                                  (shared by a seed's methods)
    digail train --method {gail,digail} [--vae R/vae_sS] [--bc-weight W] --demos D --seed S
                 --train.iterations I --train.eval-every E --train.eval-episodes 5 --out R/<method>_sS
    digail evaluate RUN --episodes 300

Budgets: 3M environment steps per run on Hopper and Walker2d, 1M on the pendulums, so the paper's
batch sizes (Table 3) with `I = budget // batch` iterations. Finished stages are skipped and a killed training
continues with `digail train --resume`, so the queue can be stopped and started again at any time; a lock per
trial keeps two queues apart. Runs live in runs/table1/ (git-ignored); the summary keeps their numbers.

On a machine without an earlier machine's runs/table1/ (a fresh clone), the committed table1.json and
table1_progress.json stand for the lost folders: `summarize` and `progress` keep their records of trials whose
folder is absent, `run`/`queue` skip a trial table1.json already holds, `publish` keeps a published median it
cannot rebuild, and `figures` draws those trials' learning curves from table1_progress.json.
"""

from __future__ import annotations

import argparse
import contextlib
import csv
import json
import os
import shlex
import subprocess
import sys
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np

from digail import paper

HERE = Path(__file__).resolve().parent
ROOT = HERE.parent / "runs" / "table1"
OUT = HERE / "results" / "table1.json"
DIGAIL = [sys.executable, "-m", "digail.cli"]

ENVS: dict[str, dict[str, Any]] = {
    # budget in env steps, the preset's batch, evaluations during training every `eval_every` iterations
    "pendulum": dict(env="Pendulum-v1", demos="digail/pendulum/expert-v0", budget=1_000_000, batch=1024,
                     eval_every=32),
    "invertedpendulum": dict(env="InvertedPendulum-v5", demos="digail/invertedpendulum/expert-v0",
                             budget=1_000_000, batch=1024, eval_every=32),
    "hopper": dict(env="Hopper-v5", demos="digail/hopper/expert-v0", budget=3_000_000, batch=4096, eval_every=25),
    "walker2d": dict(env="Walker2d-v5", demos="digail/walker2d/expert-v0", budget=3_000_000, batch=8192,
                     eval_every=12),
}
PAPER = {name: paper.table("table1")[spec["env"]] for name, spec in ENVS.items()}
"""the paper's Table 1 (`digail/paper.toml`): mean +- std return over 300 episodes; it reports no expert row"""
BC_WEIGHT = 1.0
METHODS = {
    "vae": [],
    "gail": ["--method", "gail"],
    "digail": ["--method", "digail"],
    "gail-l2": ["--method", "gail", "--bc-weight", str(BC_WEIGHT)],
    "digail-l2": ["--method", "digail", "--bc-weight", str(BC_WEIGHT)],
}
L2_ENVS = ("hopper", "walker2d")
SEEDS = (0, 1, 2)
EVAL_EPISODES = 300


def sh(args: list[str], log: Path) -> None:
    line = "digail " + " ".join(shlex.quote(a) for a in args)
    print(f"$ {line}", flush=True)
    t0 = time.perf_counter()
    with open(log, "a") as f:
        f.write(f"$ {line}\n")
        f.flush()
        subprocess.run([*DIGAIL, *args], check=True, stdout=f, stderr=subprocess.STDOUT)
    print(f"  ({time.perf_counter() - t0:.0f}s)", flush=True)


@contextlib.contextmanager
def lock(path: Path) -> Iterator[bool]:
    """An exclusive lock file (True when taken); a stale one from a killed queue is removed by hand."""
    path.parent.mkdir(parents=True, exist_ok=True)
    try:
        fd = os.open(path, os.O_CREAT | os.O_EXCL | os.O_WRONLY)
    except FileExistsError:
        yield False
        return
    try:
        os.write(fd, str(os.getpid()).encode())
        os.close(fd)
        yield True
    finally:
        path.unlink(missing_ok=True)


def train_flags(env: str, method: str, seed: int, vae: Path) -> list[str]:
    spec = ENVS[env]
    flags = [*METHODS[method], "--demos", spec["demos"], "--seed", str(seed),
             "--train.iterations", str(spec["budget"] // spec["batch"]),
             "--train.eval-every", str(spec["eval_every"]), "--train.eval-episodes", "5"]
    if method.startswith("digail"):
        flags += ["--vae", str(vae)]
    return flags


def ensure_vae(env: str, seed: int, log: Path) -> Path:
    vae = ROOT / env / f"vae_s{seed}"
    # not `.vae_s{seed}.lock`: that is the lock of the VAE column's own trial, which calls this function
    with lock(ROOT / env / f".pretrain_s{seed}.lock") as mine:
        if not mine:  # another queue is pre-training it: wait
            while not (vae / "model.pt").exists() or (ROOT / env / f".pretrain_s{seed}.lock").exists():
                time.sleep(30)
        elif not (vae / "model.pt").exists():
            sh(["pretrain", "--demos", ENVS[env]["demos"], "--seed", str(seed), "--out", str(vae), "--force"], log)
    return vae


def recorded(env: str, method: str, seed: int) -> dict[str, Any] | None:
    """The committed table1.json's record of a trial (None when it has none)."""
    if not OUT.exists():
        return None
    seeds = json.loads(OUT.read_text()).get(env, {}).get("methods", {}).get(method, {}).get("seeds", [])
    return next((r for r in seeds if r["seed"] == seed), None)


def run_trial(env: str, method: str, seed: int) -> None:
    (ROOT / env).mkdir(parents=True, exist_ok=True)
    log = ROOT / env / f"{method}_s{seed}.log"
    folder = ROOT / env / (f"vae_s{seed}" if method == "vae" else f"{method}_s{seed}")
    rec = recorded(env, method, seed)
    if rec is not None and not folder.exists() and rec["episodes"] >= EVAL_EPISODES:
        print(f"{env}:{method}:{seed} is recorded in {OUT.name} (its folder was on another machine); skipped",
              flush=True)
        return
    if method == "vae-k8":  # not a table column: the appendix's larger context, drawn by `figures`
        run = ROOT / env / f"vae_k8_s{seed}"
        with lock(ROOT / env / f".vae_k8_s{seed}.lock") as mine:
            if mine and not (run / "model.pt").exists():
                sh(["pretrain", "--demos", ENVS[env]["demos"], "--codes", "8", "--seed", str(seed), "--out", str(run),
                    "--force"], log)
        return
    with lock(ROOT / env / f".{method}_s{seed}.lock") as mine:
        if not mine:
            print(f"{env}:{method}:{seed} is running in another queue; skipped", flush=True)
            return
        vae = ensure_vae(env, seed, log) if method != "gail" and method != "gail-l2" else ROOT / env / "-"
        run = vae if method == "vae" else ROOT / env / f"{method}_s{seed}"
        if method != "vae":
            done = (run / "model.pt").exists() and _finished(run, env)
            if not done:
                if (run / "checkpoint.pt").exists():
                    sh(["train", "--resume", str(run)], log)
                else:
                    sh(["train", *train_flags(env, method, seed, vae), "--out", str(run), "--force"], log)
        if not (run / "eval.json").exists() or json.loads((run / "eval.json").read_text())["episodes"] < EVAL_EPISODES:
            sh(["evaluate", str(run), "--episodes", str(EVAL_EPISODES)], log)


def _finished(run: Path, env: str) -> bool:
    rows = _metrics(run)
    spec = ENVS[env]
    return bool(rows) and rows[-1].get("iteration", 0) >= spec["budget"] // spec["batch"]


def _iteration_seconds(rows: list[dict[str, float]]) -> float | None:
    """Training wall time of a run from its metrics: each iteration's env steps over its logged steps per second
    (`perf/sps` times the whole iteration: rollout, discriminator and PPO; the periodic evaluations and
    checkpoints are left out). None without throughput rows."""
    total, last_step = 0.0, 0.0
    for r in rows:
        if r.get("perf/sps", 0) > 0 and "step" in r:
            total += (r["step"] - last_step) / r["perf/sps"]
            last_step = r["step"]
    return round(total, 1) if total > 0 else None


def _metrics(run: Path) -> list[dict[str, float]]:
    path = run / "metrics.csv"
    if not path.exists():
        return []
    with open(path) as f:
        return [{k: float(v) for k, v in row.items() if v not in ("", None)} for row in csv.DictReader(f)]


def plan() -> list[str]:
    out = []
    for seed in SEEDS:
        for env in ENVS:
            for method in METHODS:
                if method.endswith("-l2") and env not in L2_ENVS:
                    continue
                out.append(f"{env}:{method}:{seed}")
    return out


# --------------------------------------------------------------------------------------------- summary
def trial_record(env: str, method: str, seed: int) -> dict[str, Any] | None:
    """A trial's record from its run folder's evaluation, else the committed table1.json's (its folder was on
    another machine, or it is being made again, e.g. a VAE pre-trained anew for a Directed-Info GAIL trial)."""
    run = ROOT / env / (f"vae_s{seed}" if method == "vae" else f"{method}_s{seed}")
    if not (run / "eval.json").exists():
        rec = recorded(env, method, seed)
        published = PUBLISHED / f"{env}_{method}_s{seed}"
        if rec is not None and rec.get("wall_s") is None and (published / "metrics.csv").exists():
            rec = {**rec, "wall_s": _iteration_seconds(_metrics(published))}
        return rec
    ev = json.loads((run / "eval.json").read_text())
    rows = _metrics(run)
    curve = [(r["step"], r["eval/normalized_return"]) for r in rows if "eval/normalized_return" in r]
    steps_to_09 = next((s for s, v in curve if v >= 0.9), None)
    # a VAE initialisation can score 0.9 before any training step: the first time training itself gets there
    trained_to_09 = next((s for s, v in curve if v >= 0.9 and s > 0), None)
    cfg = json.loads((run / "config.json").read_text()) if (run / "config.json").exists() else {}
    steps = int(rows[-1]["perf/global_step"]) if rows and "perf/global_step" in rows[-1] else 0
    log = ROOT / env / f"{method}_s{seed}.log"
    commands = [ln[2:].strip() for ln in log.read_text().splitlines() if ln.startswith("$ ")] if log.exists() else []
    return {
        "seed": seed, "run": str(run.relative_to(ROOT.parent.parent)),
        "mean_return": ev["mean_return"], "std_return": ev["std_return"],
        "normalized_return": ev.get("normalized_return"),
        "expert_mean_return": ev.get("expert", {}).get("mean_return"),
        "expert_std_return": ev.get("expert", {}).get("std_return"),
        "episodes": ev["episodes"], "env_steps": steps, "steps_to_0.9": steps_to_09,
        "steps_to_0.9_after_step_0": trained_to_09,
        "wall_s": cfg.get("train_time_s") or _iteration_seconds(rows),
        "commands": commands,
    }


TARGETS = {  # the benchmark's per-seed targets (the table's verdict is on the median of 3 seeds)
    "pendulum": "mean return >= the expert's mean - its std (returns are negative: normalised > 1 is worse)",
    "invertedpendulum": "mean return 1000 on every seed",
    "hopper": "normalised return >= 0.95",
    "walker2d": "normalised return >= 0.95",
}


def meets_target(env: str, rec: dict[str, Any]) -> bool | None:
    """Whether one seed's evaluation meets its env's target (None without an expert measurement)."""
    if env == "invertedpendulum":
        return bool(rec["mean_return"] >= 1000.0 - 1e-6)
    if env == "pendulum":
        if rec["expert_mean_return"] is None or rec["expert_std_return"] is None:
            return None
        return bool(rec["mean_return"] >= rec["expert_mean_return"] - rec["expert_std_return"])
    return None if rec["normalized_return"] is None else bool(rec["normalized_return"] >= 0.95)


def summarize() -> dict[str, Any]:
    table: dict[str, Any] = {}
    for env, spec in ENVS.items():
        row: dict[str, Any] = {"env_id": spec["env"], "budget_steps": spec["budget"], "paper": PAPER[env],
                               "target": TARGETS[env], "methods": {}}
        for method in METHODS:
            recs = [r for s in SEEDS if (r := trial_record(env, method, s)) is not None]
            if not recs:
                continue
            for r in recs:
                r["meets_target"] = meets_target(env, r)
            norm = [r["normalized_return"] for r in recs if r["normalized_return"] is not None]
            row["methods"][method] = {
                "seeds": recs,
                "median_mean_return": float(np.median([r["mean_return"] for r in recs])),
                "median_normalized_return": float(np.median(norm)) if norm else None,
                "complete": len(recs) == len(SEEDS),
            }
        table[env] = row
    OUT.write_text(json.dumps(table, indent=2) + "\n")
    return table


def progress() -> dict[str, Any]:
    """The learning curves (deterministic evaluations during training, 5 episodes each) of every trial that has
    started, finished or not: what a half-done table can honestly show."""
    path = OUT.with_name("table1_progress.json")
    before = json.loads(path.read_text()) if path.exists() else {}
    out: dict[str, Any] = {}
    for env in ENVS:
        for method in METHODS:
            for seed in SEEDS:
                run = ROOT / env / f"{method}_s{seed}"
                rows = _metrics(run)
                if not rows:
                    if not run.exists() and f"{env}:{method}:{seed}" in before:  # measured on another machine
                        out[f"{env}:{method}:{seed}"] = before[f"{env}:{method}:{seed}"]
                    continue
                spec = ENVS[env]
                curve = [[int(r["step"]), round(r["eval/normalized_return"], 4), round(r["eval/mean_return"], 2)]
                         for r in rows if "eval/normalized_return" in r]
                log = ROOT / env / f"{method}_s{seed}.log"
                out[f"{env}:{method}:{seed}"] = {
                    "iterations_done": int(rows[-1].get("iteration", 0)),
                    "iterations_budget": spec["budget"] // spec["batch"],
                    "env_steps": int(rows[-1].get("perf/global_step", 0)),
                    "curve_step_normalized_mean": curve,
                    "commands": [ln[2:].strip() for ln in log.read_text().splitlines() if ln.startswith("$ ")]
                    if log.exists() else [],
                }
    path.write_text(json.dumps(out, indent=1) + "\n")
    return out


NAMES = {"vae": "VAE", "gail": "GAIL", "digail": "Directed-Info GAIL", "gail-l2": "GAIL + L2",
         "digail-l2": "Directed-Info GAIL + L2"}


def _steps_to_09(rec: dict[str, Any]) -> str:
    first, trained = rec["steps_to_0.9"], rec.get("steps_to_0.9_after_step_0")
    if first is None:
        return "never"
    if first == 0 and trained is not None and trained > 0:
        return f"0 (init), {trained / 1e3:.0f}k"
    return f"{first / 1e3:.0f}k"


def markdown(table: dict[str, Any] | None = None) -> str:
    """Table 1 as Markdown: per env and method, the paper's mean +- std beside ours (median seed by mean return,
    its std over 300 episodes), every seed's normalised return, the median, the steps to 0.9 and the seeds done."""
    table = table if table is not None else json.loads(OUT.read_text())
    lines = ["| env | method | paper | ours (median seed) | normalised, per seed | median normalised "
             "| first >= 0.9 at (env steps, per seed) | target met, per seed | seeds |",
             "| --- | --- | --- | --- | --- | --- | --- | --- | --- |"]
    for row in table.values():
        for method, rec in row["methods"].items():
            paper = row["paper"].get(method)
            seeds = sorted(rec["seeds"], key=lambda r: r["mean_return"])
            mid = seeds[(len(seeds) - 1) // 2]
            norm = " / ".join(f"{r['normalized_return']:.3f}" for r in sorted(rec["seeds"], key=lambda r: r["seed"]))
            # 0.9 of a negative expert return is a better score than the expert's: no such threshold on Pendulum
            to09 = " / ".join("-" if method == "vae" or row["env_id"].startswith("Pendulum") else _steps_to_09(r)
                              for r in sorted(rec["seeds"], key=lambda r: r["seed"]))
            met = " / ".join({True: "yes", False: "no", None: "?"}[r.get("meets_target")]
                             for r in sorted(rec["seeds"], key=lambda r: r["seed"]))
            lines.append(f"| {row['env_id']} | {NAMES[method]} | "
                         f"{f'{paper[0]:.1f} +- {paper[1]:.1f}' if paper else 'n/a'} | "
                         f"{mid['mean_return']:.1f} +- {mid['std_return']:.1f} | {norm} | "
                         f"{rec['median_normalized_return']:.3f} | {to09} | {met} | {len(seeds)} of {len(SEEDS)} |")
    return "\n".join(lines)


README = HERE.parent / "docs" / "results.md"  # the page that publishes the tables
MARKERS = ("<!-- table1:start (python benchmarks/table1.py readme) -->", "<!-- table1:end -->")


def readme() -> None:
    """Replace the table between the results page's table1 markers with `markdown()` of table1.json."""
    replace_in_readme(MARKERS, markdown())


def replace_in_readme(markers: tuple[str, str], text: str) -> None:
    """Put `text` between the results page's two `markers` (shared with table2.py)."""
    page = README.read_text()
    start, end = page.index(markers[0]) + len(markers[0]), page.index(markers[1])
    README.write_text(page[:start] + "\n" + text + "\n" + page[end:])


PUBLISHED = HERE / "results" / "runs"
PUBLISH_FILES = ("model.pt", "config.json", "eval.json", "metrics.csv", "segmentation.json")


def median_record(env: str, method: str) -> dict[str, Any] | None:
    """The record of the median seed by mean return among the evaluated ones (the lower middle of an even count;
    None without any)."""
    recs = sorted((r for s in SEEDS if (r := trial_record(env, method, s)) is not None),
                  key=lambda r: r["mean_return"])
    return recs[(len(recs) - 1) // 2] if recs else None


def publish() -> list[str]:
    """Copy the median seed's run folder of every env and method with an evaluation into
    benchmarks/results/runs/<env>_<method>_s<seed>/ (small files only: no checkpoint, no TensorBoard), replacing
    an earlier median of the same env and method, so that `digail evaluate` can re-check every table cell."""
    done = []
    for env in ENVS:
        for method in METHODS:
            rec = median_record(env, method)
            if rec is None:
                continue
            src = ROOT.parent.parent / rec["run"]
            dest = PUBLISHED / f"{env}_{method}_s{rec['seed']}"
            if not (src / "eval.json").exists():  # the median's evaluated folder was on another machine
                if not dest.exists():
                    print(f"{env}:{method}: the median seed {rec['seed']} is neither here nor published; kept "
                          "the published folder", file=sys.stderr)
                continue
            publish_run(src, dest)
            done.append(str(dest.relative_to(HERE.parent)))
    return done


def publish_run(src: Path, dest: Path) -> None:
    """Copy a run folder's small files (and figures) to `dest` under benchmarks/results/runs/, replacing the
    folder of another seed of the same cell (`<env>_<method>_s<seed>`; shared with table2.py)."""
    import shutil

    prefix = dest.name.rsplit("_s", 1)[0]
    for old in dest.parent.glob(f"{prefix}_s*"):
        if old != dest:
            shutil.rmtree(old)
    dest.mkdir(parents=True, exist_ok=True)
    for name in PUBLISH_FILES:
        if (src / name).exists():
            shutil.copy2(src / name, dest / name)
    if (src / "figures").is_dir():
        shutil.copytree(src / "figures", dest / "figures", dirs_exist_ok=True)


# --------------------------------------------------------------------------------------------- figures
FIGURES = HERE / "results" / "figures" / "table1"
ROLLOUTS = 5  # closed-loop episodes drawn and scored per run (evaluation seeds 10000 + i)


def _median_seed_run(env: str, method: str) -> Path | None:
    """The run folder of the median seed by normalised return (of those evaluated), else any trained one."""
    rec = median_record(env, method)
    if rec is not None:
        run = ROOT.parent.parent / rec["run"]
        published = PUBLISHED / f"{env}_{method}_s{rec['seed']}"
        return run if (run / "model.pt").exists() or not (published / "model.pt").exists() else published
    runs = sorted(p for p in (ROOT / env).glob(f"{method}_s*") if (p / "model.pt").exists())
    return runs[0] if runs else None


def _curves(env: str, method: str, seed: int) -> Path | dict[str, np.ndarray] | None:
    """A trial's learning curves: its run folder, else its eval/* curve in table1_progress.json (folder lost)."""
    run = ROOT / env / f"{method}_s{seed}"
    if (run / "metrics.csv").exists():
        return run
    path = OUT.with_name("table1_progress.json")
    rec = json.loads(path.read_text()).get(f"{env}:{method}:{seed}") if path.exists() else None
    if run.exists() or not rec or not rec["curve_step_normalized_mean"]:
        return None
    curve = np.asarray(rec["curve_step_normalized_mean"], dtype=float)
    return {"step": curve[:, 0], "eval/normalized_return": curve[:, 1], "eval/mean_return": curve[:, 2]}


def figures() -> dict[str, Any]:
    """The paper's figures for Table 1 from the runs so far, and the agreement of codes with the gait.

    Learning curves per env (eval/* against env steps, mean and min-max over seeds per method); for Hopper and
    Walker2d, code strips of demonstrations and of Directed-Info GAIL rollouts (median seed) and the mutual
    information of their codes with the hip's gait phase (`digail.eval.gait`); for Pendulum the code map (angle
    against angular velocity); for Hopper the K = 8 VAE's PCA of expert states coloured by code.
    """
    from digail.algos.decode import segment_many
    from digail.checkpoint import load_model
    from digail.data.minari_io import load_dataset
    from digail.eval.gait import code_phase_scores, gait_phase, phase_stats
    from digail.viz import figures as F
    from digail.viz.video import play_episodes

    FIGURES.mkdir(parents=True, exist_ok=True)
    codes_json = HERE / "results" / "table1_codes.json"
    before = json.loads(codes_json.read_text()) if codes_json.exists() else {}
    out: dict[str, Any] = {}
    for env, spec in ENVS.items():
        runs = {m: [_curves(env, m, s) for s in SEEDS] for m in METHODS if m != "vae"}
        runs = {m: [c for c in cs if c is not None] for m, cs in runs.items()}
        runs = {m: cs for m, cs in runs.items() if cs}
        rec: dict[str, Any] = {"figures": []}
        if runs and (p := F.learning_curves_multi(runs, FIGURES / f"{env}_learning_curves.png")) is not None:
            rec["figures"].append(str(p.relative_to(HERE.parent)))
        run = _median_seed_run(env, "digail")
        if run is None:
            out[env] = rec
            continue
        model, _ = load_model(run / "model.pt")
        demos = load_dataset(spec["demos"]).trajs
        demo_codes = segment_many(model, demos)
        demo_obs = [np.asarray(t.obs[:len(t)]) for t in demos]
        gen = play_episodes(model, spec["env"], ROLLOUTS, 10_000, render=False)
        gen_obs, gen_codes = [np.asarray(e.obs)[:len(e.codes)] for e in gen], [np.asarray(e.codes) for e in gen]
        rec["run"] = str(run.relative_to(HERE.parent))
        # the phase label's standardisation comes from the demonstrations, shared by every score below
        stats = phase_stats(demo_obs, spec["env"]) if env in ("hopper", "walker2d") else None
        if stats is not None:
            rec["figures"].append(str(F.code_strips(
                {f"demonstrations (codes from q), {spec['env']}": demo_codes,
                 "Directed-Info GAIL closed-loop rollouts": gen_codes},
                FIGURES / f"{env}_codes_time.png").relative_to(HERE.parent)))
            rec["code_gait"] = {
                "demonstrations": code_phase_scores(demo_codes, [gait_phase(o, spec["env"], stats) for o in demo_obs]),
                "rollouts": code_phase_scores(gen_codes, [gait_phase(o, spec["env"], stats) for o in gen_obs]),
            }
        if env == "pendulum":
            rec["figures"].append(str(F.pendulum_code_map(
                demo_obs + gen_obs, demo_codes + gen_codes, FIGURES / "pendulum_code_map.png",
                title="Pendulum-v1: demonstrations and Directed-Info GAIL rollouts").relative_to(HERE.parent)))
        if env == "hopper" and (ROOT / env / "vae_k8_s0" / "model.pt").exists():
            k8, _ = load_model(ROOT / env / "vae_k8_s0" / "model.pt")
            k8_codes = segment_many(k8, demos)
            rec["figures"].append(str(F.state_pca(
                demo_obs, k8_codes, FIGURES / "hopper_k8_pca.png",
                title="Hopper-v5 expert states (PCA), coloured by the K = 8 VAE's code").relative_to(HERE.parent)))
            assert stats is not None
            rec["code_gait_k8_demonstrations"] = code_phase_scores(
                k8_codes, [gait_phase(o, spec["env"], stats) for o in demo_obs])
        elif env == "hopper" and "code_gait_k8_demonstrations" in before.get(env, {}):
            # the K = 8 VAE was made on another machine: keep its committed figure and scores
            rec["figures"].append(str((FIGURES / "hopper_k8_pca.png").relative_to(HERE.parent)))
            rec["code_gait_k8_demonstrations"] = before[env]["code_gait_k8_demonstrations"]
        out[env] = rec
    codes_json.write_text(json.dumps(out, indent=1) + "\n")
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    sub = ap.add_subparsers(dest="cmd", required=True)
    r = sub.add_parser("run")
    r.add_argument("env", choices=list(ENVS))
    r.add_argument("method", choices=[*METHODS, "vae-k8"])
    r.add_argument("seed", type=int)
    q = sub.add_parser("queue")
    q.add_argument("trials", nargs="+", help="env:method:seed")
    sub.add_parser("summarize")
    sub.add_parser("plan")
    sub.add_parser("progress")
    sub.add_parser("figures")
    sub.add_parser("markdown")
    sub.add_parser("publish")
    sub.add_parser("readme")
    args = ap.parse_args()
    if args.cmd == "run":
        run_trial(args.env, args.method, args.seed)
    elif args.cmd == "queue":
        for trial in args.trials:
            env, method, seed = trial.split(":")
            try:
                run_trial(env, method, int(seed))
            except subprocess.CalledProcessError as exc:
                print(f"{trial} failed ({exc}); see its log; next trial", flush=True)
    elif args.cmd == "plan":
        print(" ".join(plan()))
    elif args.cmd == "markdown":
        print(markdown())
    elif args.cmd == "readme":
        readme()
    elif args.cmd == "publish":
        print("\n".join(publish()))
    elif args.cmd == "figures":
        print(json.dumps(figures(), indent=1))
    elif args.cmd == "progress":
        for name, rec in progress().items():
            print(name, rec["env_steps"], rec["curve_step_normalized_mean"][-3:])
    else:
        print(json.dumps(summarize(), indent=1)[:4000])


if __name__ == "__main__":
    main()
