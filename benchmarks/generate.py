"""Data generation from sub-tasks (`digail generate`), then behaviour cloning on what it generated.

    python benchmarks/generate.py run --task fetch --demos 1 --seeds 0 1 2 --sizes 100 500 1000 --methods bc flatbc
    python benchmarks/generate.py run --task pick-place --demos 3 --seeds 0 --segments codes ...
    python benchmarks/generate.py table --out benchmarks/results/generate/generate.json [--publish]
        [--keep benchmarks/results/generate/generate.json]   (keep what the earlier table measured that is not here)
    python benchmarks/generate.py figure   # -> benchmarks/results/figures/generate_paths.png

A job (task, source demonstrations N, seed S, segment source) runs, resumably, under
`runs/generate/<task>/<segments>/d<N>_s<S>/`:

    digail generate --demos D --sources <N episodes: S*N .. S*N+N-1> --segments SEG --attempts A --successes MAX
        --seed 1000000+100000*S --out .../data          (SEG codes: --vae .../vae, a `digail pretrain` of the sources
                                                         with K = the labels' count, the task's preset)
    digail pretrain --demos .../data --demos-episodes SIZE --codes K --seed S --preset P --out .../<method>_n<SIZE>
    digail evaluate .../<method>_n<SIZE> --episodes 100   (fresh scenes: the evaluation seeds, 10000 on)

`--bc-args "FLAGS" --bc-name NAME` adds flags to those behaviour-cloning pre-trainings (e.g. more gradient steps
for 1000 demonstrations: `--vae.init-steps 30000`); their rows are named `<method>-NAME`, beside the plain ones.
`bc` is the VAE's policy with K codes (Fetch 4, a Meta-World task its expert's phase count), closed-loop q; `flatbc`
the same pre-training with one code; `digail-l2` is Directed-Info GAIL + L2 started from `bc`'s VAE (the same size):

    digail train --demos .../data --demos-episodes SIZE --vae .../bc_n<SIZE> --seed S --preset P
        --train.bc-weight 1.0 --train.iterations I --out .../digail-l2_n<SIZE>    (a killed one: --resume)

Every command is kept in the job's `commands.json`. `table` gathers the jobs
into one JSON: per job the generation (attempts, successes, rate, env steps), per trained row its success rate, the
env steps generation spent on its SIZE demonstrations, and the training env steps (0 for behaviour cloning; the
run's own count for `digail-l2`), with medians over seeds.
"""

from __future__ import annotations

import argparse
import json
import shlex
import statistics
from pathlib import Path
from typing import Any

ROOT = Path("runs/generate")
FETCH = {"env_id": "digail/FetchPickAndPlace-v4", "demos": "digail/fetchpickandplace/expert-v0", "preset": "fetch",
         "codes": 4}


ROUTE = {"env_id": "digail/LandmarkRoute-v0", "demos": "digail/landmarkroute/expert-v0", "preset": "landmark-route",
         "codes": 4, "generate": ["--order", "3,2,1,0", "--env-arg", "order=3,2,1,0"],
         "evaluate": ["--env-arg", "order=3,2,1,0"]}
"""the landmark route driven in an order never demonstrated (3,2,1,0; the demonstrations drive 0,2,1,3): generation
chains the legs in that order and the env succeeds only on it, in generation and in the evaluation"""


def task_info(task: str) -> dict[str, Any]:
    """The env, the source dataset, the preset and K of a task (`fetch`, `landmark-route` or a Meta-World task such
    as pick-place)."""
    if task == "fetch":
        return FETCH
    if task == "landmark-route":
        return ROUTE
    from digail.envs.metaworld import phase_counts

    return {"env_id": f"metaworld/{task}-v3", "demos": f"digail/metaworld-{task}/expert-v0", "preset": "metaworld",
            "codes": phase_counts()[f"{task}-v3"]}


def digail(cmd: list[str], log: list[list[str]], job: Path, may_fail: bool = False) -> None:
    """Run one digail command in-process, noting it in the job's commands.json first."""
    from digail.cli import main

    if cmd not in log:
        log.append(cmd)
        (job / "commands.json").write_text(json.dumps([shlex.join(["digail", *c]) for c in log], indent=1))
    print("$ digail " + shlex.join(cmd), flush=True)
    if main(cmd) != 0 and not may_fail:
        raise SystemExit(f"failed: digail {shlex.join(cmd)}")


def run_job(task: str, n: int, seed: int, segments: str, args: argparse.Namespace) -> None:
    info = task_info(task)
    job = ROOT / task / (segments + (f"-{args.tag}" if args.tag else "")) / f"d{n}_s{seed}"
    job.mkdir(parents=True, exist_ok=True)
    log = _saved(job)
    sources = ",".join(str(i) for i in range(seed * n, seed * n + n))
    data = job / "data"
    if not data.exists():
        extra: list[str] = []
        if segments == "codes":
            vae = job / "vae"
            if not (vae / "model.pt").exists():
                digail(["pretrain", "--demos", info["demos"], "--demos-episodes", str(seed * n + n), "--codes",
                        str(info["codes"]), "--seed", str(seed), "--preset", info["preset"], "--out", str(vae),
                        "--force"], log, job)
            extra = ["--vae", str(vae)]
        if segments == "chunks":
            extra = ["--chunk", str(args.chunk)]
        stop = ["--successes", str(max(args.sizes))] if args.sizes else []
        digail(["generate", "--demos", info["demos"], "--sources", sources, "--segments", segments, *extra,
                "--attempts", str(args.attempts), *stop, "--seed", str(1_000_000 + 100_000 * seed),
                *info.get("generate", []), *args.generate_args, "--out", str(data)], log, job, may_fail=True)
        if not data.exists():  # no attempt succeeded: the rate is 0, and there is nothing to train on
            return
    have = _generation(data)["successes"]
    for size in args.sizes:
        if size > have:
            print(f"{job}: {have} demonstrations generated, fewer than {size}; row skipped")
            continue
        for method in args.methods:
            run = job / f"{method}{'-' + args.bc_name if args.bc_name else ''}_n{size}"
            if (run / "eval.json").exists():
                continue
            if method == "digail-l2":  # Directed-Info GAIL + L2 from the BC-with-codes VAE of the same size
                bc = job / f"bc{'-' + args.bc_name if args.bc_name else ''}_n{size}"
                if not (bc / "model.pt").exists():
                    pretrain(data, size, info["codes"], seed, info["preset"], bc, log, job, args.bc_args)
                if (run / "checkpoint.pt").exists():  # a killed training continues
                    digail(["train", "--resume", str(run)], log, job)
                else:
                    digail(["train", "--demos", str(data), "--demos-episodes", str(size), "--vae", str(bc),
                            "--seed", str(seed), "--preset", info["preset"], "--train.bc-weight", "1.0",
                            "--train.iterations", str(args.train_iterations), "--train.eval-every", "10",
                            "--train.eval-episodes", "10", "--out", str(run), "--force"], log, job)
            elif not (run / "model.pt").exists():
                pretrain(data, size, info["codes"] if method == "bc" else 1, seed, info["preset"], run, log, job,
                         args.bc_args)
            digail(["evaluate", str(run), "--episodes", str(args.eval_episodes), *info.get("evaluate", [])], log, job)


def pretrain(data: Path, size: int, codes: int, seed: int, preset: str, run: Path, log: list[list[str]],
             job: Path, extra: str = "") -> None:
    """Behaviour cloning on the first `size` generated demonstrations: the VAE's policy with `codes` codes."""
    digail(["pretrain", "--demos", str(data), "--demos-episodes", str(size), "--codes", str(codes), "--seed",
            str(seed), "--preset", preset, "--out", str(run), "--force", *shlex.split(extra)], log, job)


def _saved(job: Path) -> list[list[str]]:
    path = job / "commands.json"
    return [shlex.split(c)[1:] for c in json.loads(path.read_text())] if path.exists() else []


def _generation(data: Path) -> dict[str, Any]:
    partial = data.with_name(data.name + ".partial") / "state.json"
    if not data.exists() and partial.exists():  # a generation that kept nothing leaves only its progress
        state = json.loads(partial.read_text())
        return {**state, "rate": state["successes"] / max(state["attempts"], 1),
                "frames": state["plan"]["frames"], "order": None}
    meta = json.loads((data / "data" / "metadata.json").read_text())
    return meta["digail"]["generation"]


def _trained(run: Path) -> int:
    """Env steps a run trained on: 0 for a VAE (behaviour cloning), the last logged count of a training run."""
    import csv

    metrics = run / "metrics.csv"
    if not metrics.exists():
        return 0
    with metrics.open() as f:
        rows = list(csv.DictReader(f))
    last = rows[-1] if rows else None
    return int(float(last["step"])) if last and last.get("step") else 0


def _steps_for(gen: dict[str, Any], size: int) -> int:
    """Env steps generation spent until its `size`-th kept demonstration (with `--frame-trials` or `--pick best`, the
    trials' too)."""
    ep = gen["episodes"][size - 1]
    trials = sum(int((gen.get(k) or {}).get("env_steps", 0)) for k in ("frame_trials", "source_trials"))
    if "env_steps" in ep:
        return int(ep["env_steps"]) + trials
    return round((ep["attempt"] + 1) * gen["env_steps"] / gen["attempts"]) + trials  # equal-length attempts (Fetch)


def table(args: argparse.Namespace) -> dict[str, Any]:
    jobs, rows = [], []
    for job in sorted(ROOT.glob("*/*/d*_s*")):
        data = job / "data"
        if not data.exists() and not (job / "data.partial").exists():
            continue
        task, segments = job.parent.parent.name, job.parent.name
        if args.task and task not in args.task:
            continue
        n, seed = (int(x[1:]) for x in job.name.split("_"))
        gen = _generation(data)
        jobs.append({"task": task, "segments": segments, "demos": n, "seed": seed, "attempts": gen["attempts"],
                     "successes": gen["successes"], "rate": round(gen["rate"], 4), "env_steps": gen["env_steps"],
                     # the same attempts (seeds) for every segment source: the first 200
                     "rate_first_200": round(sum(e["attempt"] < 200 for e in gen["episodes"])
                                             / min(200, gen["attempts"]), 4),
                     "frames": gen["frames"], "order": gen.get("order"),
                     **{k: gen[k] for k in ("frame_trials", "source_trials") if gen.get(k)},
                     "commands": [shlex.join(["digail", *c]) for c in _saved(job)
                                  if c[0] == "generate" or str(job / "vae") in c]})
        for run in sorted(job.glob("*_n*")):
            if not (run / "eval.json").exists():
                continue
            method, size = run.name.rsplit("_n", 1)
            ev = json.loads((run / "eval.json").read_text())
            rows.append({"task": task, "segments": segments, "demos": n, "seed": seed, "method": method,
                         "size": int(size), "success_rate": ev.get("success_rate"),
                         "generation_env_steps": _steps_for(gen, int(size)), "training_env_steps": _trained(run),
                         "run": str(run), "commands": [shlex.join(["digail", *c]) for c in _saved(job)
                                                        if str(run) in c]})
    if args.keep and args.keep.exists():
        _keep_earlier(json.loads(args.keep.read_text()), jobs, rows, args.task)
    medians = []
    keys = sorted({(r["task"], r["segments"], r["demos"], r["method"], r["size"]) for r in rows})
    for key in keys:
        group = [r for r in rows if (r["task"], r["segments"], r["demos"], r["method"], r["size"]) == key]
        gens = [j for j in jobs if (j["task"], j["segments"], j["demos"]) == key[:3]]
        medians.append({"task": key[0], "segments": key[1], "demos": key[2], "method": key[3], "size": key[4],
                        "seeds": sorted(r["seed"] for r in group),
                        "median_success": statistics.median(r["success_rate"] for r in group),
                        "success_by_seed": [r["success_rate"] for r in sorted(group, key=lambda r: r["seed"])],
                        "median_generation_rate": statistics.median(j["rate"] for j in gens),
                        "median_generation_env_steps": statistics.median(r["generation_env_steps"] for r in group),
                        "training_env_steps": statistics.median(r["training_env_steps"] for r in group)})
    if args.publish:  # the median seed's run folder of every row with three seeds, beside the other published runs
        from digail.sweep.publish import portable_text, publish_run

        for m in medians:
            group = [r for r in rows if (r["task"], r["segments"], r["demos"], r["method"], r["size"])
                     == (m["task"], m["segments"], m["demos"], m["method"], m["size"])]
            if len(group) < 3:
                continue
            median = sorted(group, key=lambda r: r["success_rate"])[len(group) // 2]
            dest = Path("benchmarks/results/runs") / (f"generate_{m['task']}_{m['segments']}_d{m['demos']}_"
                                                      f"{m['method']}_n{m['size']}_s{median['seed']}")
            if not Path(median["run"]).exists():  # a kept job's run: published where it was measured, if it was
                if dest.exists():
                    m["median_run"] = str(dest)
                continue
            publish_run(Path(median["run"]), dest)
            for file in dest.glob("*.json"):  # publish_run makes config.json portable; segmentation.json too
                file.write_text(portable_text(file.read_text()))
            m["median_run"] = str(dest)
    result = {"about": "digail generate from N source demonstrations, then behaviour cloning on SIZE generated "
              "ones; success over 100 evaluation episodes on fresh scenes (seeds 10000 on)",
              "script": "benchmarks/generate.py", "jobs": jobs, "rows": rows, "table": medians}
    if args.out:
        args.out.parent.mkdir(parents=True, exist_ok=True)
        args.out.write_text(json.dumps(result, indent=1) + "\n")
    for m in medians:
        print(f"{m['task']:16s} {m['segments']:7s} d{m['demos']} {m['method']:7s} n{m['size']:<5d} success "
              f"{m['median_success']:.2f} {m['success_by_seed']} gen rate {m['median_generation_rate']:.2f} "
              f"gen steps {m['median_generation_env_steps']:.0f}")
    return result


def _job_key(x: dict[str, Any]) -> tuple[Any, ...]:
    return x["task"], x["segments"], x["demos"], x["seed"]


def _keep_earlier(earlier: dict[str, Any], jobs: list[dict[str, Any]], rows: list[dict[str, Any]],
                  tasks: list[str] | None) -> None:
    """Add to `jobs` and `rows` what an earlier table measured and this machine has no run of (another machine's
    jobs, or sizes a job here did not train). A job generated here and earlier keeps the longer generation's record;
    the attempts' seeds are the same, so the shorter one's kept demonstrations are the first of the longer's (checked
    on the first 200 attempts)."""
    wanted = [x for x in earlier["jobs"] if not tasks or x["task"] in tasks]
    here = {_job_key(j): i for i, j in enumerate(jobs)}
    for job in wanted:
        i = here.get(_job_key(job))
        if i is None:
            jobs.append(job)
            continue
        if job["rate_first_200"] != jobs[i]["rate_first_200"]:
            raise SystemExit(f"{_job_key(job)}: the earlier table's first 200 attempts kept a share of "
                             f"{job['rate_first_200']}, this machine's {jobs[i]['rate_first_200']}: not the same "
                             "generation; move one of them to another --tag.")
        if job["attempts"] > jobs[i]["attempts"]:
            jobs[i] = job
    have = {(*_job_key(r), r["method"], r["size"]) for r in rows}
    rows += [r for r in earlier["rows"] if (*_job_key(r), r["method"], r["size"]) not in have
             and (not tasks or r["task"] in tasks)]


def figure(args: argparse.Namespace) -> Path:
    """The source demonstration's gripper path beside generated ones in new scenes, seen from above (x, y) and from
    the side (x, z), each with its object's start and its goal."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    import numpy as np

    from digail.data.minari_io import load_dataset

    gen = load_dataset(args.data)
    record = gen.metadata["digail"]["generation"]
    source = load_dataset(record["demos"]).trajs[record["sources"][0]]
    fig, axes = plt.subplots(1, 2, figsize=(10, 4.2))
    colours = plt.get_cmap("tab10")
    shown = [("source", source, "black")] + [(f"generated {i}", t, colours(i % 10))
                                             for i, t in enumerate(gen.trajs[:args.episodes])]
    for name, traj, colour in shown:
        obs = np.asarray(traj.obs)
        for ax, (a, b) in zip(axes, ((0, 1), (0, 2)), strict=True):
            ax.plot(obs[:, a], obs[:, b], color=colour, lw=2.2 if name == "source" else 1.0,
                    label=name if a == 0 and b == 1 and name == "source" else None)
            ax.scatter(obs[0, 3 + a], obs[0, 3 + b], color=colour, marker="s", s=30)
            ax.scatter(obs[0, 25 + a], obs[0, 25 + b], color=colour, marker="*", s=80)
    for ax, (x, y) in zip(axes, (("x", "y"), ("x", "z")), strict=True):
        ax.set_xlabel(f"{x} (m)")
        ax.set_ylabel(f"{y} (m)")
    axes[0].set_title("from above")
    axes[1].set_title("from the side")
    axes[0].legend(loc="best", fontsize=8)
    fig.suptitle(f"Fetch: the source demonstration (black) and {len(shown) - 1} generated in new scenes; "
                 "square: the cube at the start, star: the goal", fontsize=10)
    fig.tight_layout()
    args.out.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(args.out, dpi=110)
    print(f"wrote {args.out}")
    return args.out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    sub = parser.add_subparsers(dest="what", required=True)
    r = sub.add_parser("run", help="generate and train (resumable)")
    r.add_argument("--task", nargs="+", default=["fetch"])
    r.add_argument("--demos", type=int, nargs="+", default=[1])
    r.add_argument("--seeds", type=int, nargs="+", default=[0])
    r.add_argument("--segments", nargs="+", default=["labels"])
    r.add_argument("--sizes", type=int, nargs="*", default=[100, 500, 1000], help="none: generation only")
    r.add_argument("--methods", nargs="*", default=["bc", "flatbc"], help="bc, flatbc, digail-l2")
    r.add_argument("--train-iterations", type=int, default=50,
                   help="digail-l2: PPO iterations (the fetch preset's 4096 env steps each)")
    r.add_argument("--attempts", type=int, default=1500)
    r.add_argument("--chunk", type=int, default=10)
    r.add_argument("--eval-episodes", type=int, default=100)
    r.add_argument("--generate-args", nargs="*", action="extend", default=[],
                   help="more `digail generate` flags, e.g. --generate-args=--gain=0.5 (given again, added to)")
    r.add_argument("--bc-args", default="", metavar="FLAGS", help="more `digail pretrain` flags for bc and flatbc")
    r.add_argument("--bc-name", default="", help="the name those rows take: <method>-NAME")
    r.add_argument("--tag", default="", help="a variant's name: its jobs go to runs/generate/<task>/<segments>-<tag>")
    t = sub.add_parser("table", help="gather the jobs into one JSON")
    t.add_argument("--task", nargs="*")
    t.add_argument("--out", type=Path)
    t.add_argument("--publish", action="store_true", help="copy each row's median run to benchmarks/results/runs")
    t.add_argument("--keep", type=Path, metavar="JSON",
                   help="an earlier table: its jobs and rows that runs/generate has no run of are kept")
    f = sub.add_parser("figure", help="source and generated gripper paths (Fetch)")
    f.add_argument("--data", default="runs/generate/fetch/labels/d1_s0/data")
    f.add_argument("--episodes", type=int, default=6)
    f.add_argument("--out", type=Path, default=Path("benchmarks/results/figures/generate_paths.png"))
    args = parser.parse_args()
    if args.what == "figure":
        figure(args)
        return
    if args.what == "table":
        table(args)
        return
    if args.bc_args and not args.bc_name:
        parser.error("--bc-args needs --bc-name, so those rows do not take the plain rows' folders")
    for task in args.task:
        for segments in args.segments:
            for n in args.demos:
                for seed in args.seeds:
                    run_job(task, n, seed, segments, args)


if __name__ == "__main__":
    main()
