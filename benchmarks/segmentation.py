"""Segmentation benchmark: `digail pretrain` + `digail segment` with the defaults, K given, on data no
setting was tuned for.

    python benchmarks/segmentation.py    # every task, seeds 0 1 2 -> benchmarks/results/segmentation/segmentation.json
    python benchmarks/segmentation.py --tasks shuttle square --seeds 0 --out runs/seg.json
    python benchmarks/segmentation.py --set vae.smoothing-weight=0.3 ...   (extra flags for every `digail pretrain`)

Tasks: the waypoint courses of `digail.envs.waypoints.COURSES` (recorded once per seed 0 with Minari's API by
`digail.data.courses.record_course` into `--data`, default runs/segbench/datasets), among them the harder ones
(curved legs joined smoothly, legs that weave, distractor dimensions, episodes that start in a random sub-task,
eight short sub-tasks); three shipped data sets: Circle-World (K = 2), Four Rooms (K = 5, label = the next corridor
or the apple) and the Fetch phases (K = 4: reach, grasp, carry, place); and Hopper's gait phase (K = 4: the shipped
Hopper demonstrations' first 8 episodes labelled by `digail.eval.gait.gait_phase`, written once into `--data`); and
sixteen Meta-World tasks (`metaworld-<task>`: the shipped demonstrations of the scripted expert, its phases as the label
with runs under `digail.envs.metaworld.MIN_SEGMENT` steps merged, written once into `--data`; K = the phases left);
and two robosuite tasks (`robosuite-stack`, `robosuite-pickplacecan`: the fixtures of tests/data/robosuite imported
with `digail import`, the scripted expert's phases from the oracle file beside them as the label, merged the same
way). The shipped ones and robosuite's run with `--preset default`, the settings an env without a preset gets, so
every task sees the same defaults. Each (task, seed) runs exactly what a user types:

    digail pretrain --demos D --codes K --seed S --out R/<task>_sS [--preset default]
    digail segment R/<task>_sS

(in this process, through `digail.cli.main`, so the imports are paid once). The table holds per seed the
accuracy, NMI, boundary F1, switches per episode and the truth's, the pre-training time, and their medians.

Two measurements of the label-free choices (`digail.algos.model_selection`), written beside the table:

    python benchmarks/segmentation.py --measure restarts --restarts 3 --tasks ... -> segmentation_restarts.json
        per (task, seed): N restarts on the same split as `--vae.restarts N`, each one's held-out description
        length and accuracy on all demonstrations; a hit when the lowest description length is also the most
        accurate (ties count)
    python benchmarks/segmentation.py --measure figure   -> results/figures/segmentation_benchmark.png (the runs
        of the table's seed 0: oracle labels against the codes for three demonstrations per task)
    python benchmarks/segmentation.py --measure codes --tasks ...               -> segmentation_codes.json
        per (task, seed): `digail pretrain --codes auto` (K = 2 .. 8), its curve, and whether it chose the true K
        (the number of distinct oracle labels); `--set vae.k-criterion=vae` measures the other criterion;
        `--curve-only` computes the curve and the choice exactly as `--codes auto` does but skips training the
        chosen K's VAE afterwards (which does not change the choice)
    python benchmarks/segmentation.py --measure codes-figure \
        --out benchmarks/results/segmentation/segmentation_codes_auto.json
        -> results/figures/segmentation_codes.png: every task's curve of seed 0, the choice and the true K
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import os
import shlex
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np

from digail.cli import main as digail
from digail.data.courses import record_course
from digail.envs.waypoints import COURSES

HERE = Path(__file__).resolve().parent

SHIPPED: dict[str, dict[str, Any]] = {
    "circle-world": dict(demos="digail/circleworld/expert-v0", codes=2,
                         description="Circle-World: clockwise then counter-clockwise (shipped, 12 000 steps)"),
    # K = 5: the label takes five values (four corridors and the apple); with four codes one-to-one accuracy cannot
    # pass 1 - 0.124 = 0.876 on these demonstrations, whatever the segmentation
    "four-rooms": dict(demos="digail/fourrooms/expert-v0", codes=5,
                       description="Four Rooms: the next corridor (shipped)"),
    "fetch": dict(demos="digail/fetchpickandplace/expert-v0", codes=4,
                  description="FetchPickAndPlace phases reach / grasp / carry / place (shipped, 25 000 steps)"),
    "landmark-route": dict(demos="digail/landmarkroute/expert-v0", codes=4,
                           description="Landmark route: four legs, the landmark heading for (shipped, about 20 000 "
                                       "steps)"),
}

DERIVED: dict[str, dict[str, Any]] = {
    "hopper-gait": dict(source="digail/hopper/expert-v0", env="Hopper-v5", episodes=8, codes=4,
                        description="Hopper's gait phase: 4 sectors of the hip's phase portrait (shipped Hopper "
                                    "demonstrations, first 8 episodes, about 8 000 steps)"),
}
"""shipped data sets relabelled with a phase computed from the observation (written into `--data` once)"""

METAWORLD = ("pick-place", "assembly", "stick-pull", "shelf-place", "basketball", "disassemble", "peg-insert-side",
             "box-close", "hammer", "push-wall", "plate-slide-back", "stick-push", "door-lock", "hand-insert",
             "pick-out-of-hole", "coffee-pull")
"""Meta-World tasks: the shipped demonstrations (50 episodes of the scripted expert) with the expert's phase as the
label, runs shorter than `digail.envs.metaworld.MIN_SEGMENT` steps merged into their neighbour (written into `--data`
once); K is the number of phases left"""

ROBOSUITE = {"robosuite-stack": "stack", "robosuite-pickplacecan": "pickplacecan"}
"""robosuite tasks: the fixtures of `tests/data/robosuite` (scripted Stack and PickPlaceCan demonstrations in
robomimic's layout, made by `scripts/robosuite_producer/produce.py`), imported as a user would (`digail import`),
with the scripted expert's phase from the oracle file beside them as the label (runs under `MIN_SEGMENT` steps
merged); K is the number of phases left"""

KEYS = ("accuracy", "nmi", "boundary_f1", "boundary_f1_5", "switches_per_episode", "true_switches_per_episode",
        "time_s", "cpu_s")


def task_names() -> list[str]:
    return [*COURSES, *SHIPPED, *DERIVED, *(f"metaworld-{t}" for t in METAWORLD), *ROBOSUITE]


def derived_dataset(name: str, data_root: Path) -> Path:
    """The folder of derived task `name`'s data set: the source's first episodes with their phase as the label."""
    from digail.data.minari_io import load_dataset
    from digail.data.minari_write import write_dataset
    from digail.eval.gait import gait_phase, phase_stats

    spec = DERIVED[name]
    folder = (data_root / f"segbench-{name}").resolve()
    if (folder / "data" / "metadata.json").is_file():
        return folder
    trajs = load_dataset(spec["source"]).trajs[:spec["episodes"]]
    stats = phase_stats([t.obs for t in trajs], spec["env"])
    labelled = [dataclasses.replace(t, subtasks=gait_phase(t.obs, spec["env"], stats, spec["codes"])) for t in trajs]
    write_dataset(labelled, folder, spec["env"], f"segbench/{name}-v0", description=spec["description"])
    return folder


def metaworld_dataset(name: str, data_root: Path) -> tuple[Path, int, str]:
    """The folder of Meta-World task `name`'s data set (the shipped one, flickers merged), K and its description."""
    from digail.data.minari_io import load_dataset
    from digail.data.minari_write import write_dataset
    from digail.envs.metaworld import MIN_SEGMENT, merge_short_runs

    task = name.removeprefix("metaworld-")
    folder = (data_root / f"segbench-{name}").resolve()
    if not (folder / "data" / "metadata.json").is_file():
        ds = load_dataset(f"digail/{name}/expert-v0")
        labelled = [dataclasses.replace(t, subtasks=merge_short_runs(np.asarray(t.subtasks), MIN_SEGMENT))
                    for t in ds.trajs]
        write_dataset(labelled, folder, ds.env_id or f"metaworld/{task}-v3", f"segbench/{name}-v0",
                      description=f"Meta-World {task}: the expert's phases, runs under {MIN_SEGMENT} steps merged")
    labels = np.concatenate([np.asarray(t.subtasks) for t in load_dataset(folder).trajs])
    codes = len(np.unique(labels))
    return folder, codes, (f"Meta-World {task}: the scripted expert's {codes} phases (shipped, 50 episodes, "
                           f"{len(labels) - 50} steps)")


def robosuite_dataset(name: str, data_root: Path) -> tuple[Path, int, str]:
    """The folder of robosuite task `name`'s data set (the fixture imported, the expert's phases as the label), K and
    its description."""
    import h5py

    from digail.data.minari_io import load_dataset
    from digail.data.minari_write import write_dataset
    from digail.envs.metaworld import MIN_SEGMENT, merge_short_runs

    source = HERE.parent / "tests" / "data" / "robosuite" / f"{ROBOSUITE[name]}.hdf5"
    folder = (data_root / f"segbench-{name}").resolve()
    if not (folder / "data" / "metadata.json").is_file():
        imported = data_root / f"import-{name}"
        if not (imported / "data" / "metadata.json").is_file() and digail(
                ["import", str(source), "--out", str(imported), "--force"]) != 0:
            raise SystemExit(f"digail import failed on {source}")
        ds = load_dataset(imported)
        with h5py.File(source.with_suffix(".oracle.hdf5"), "r") as oracle:
            phases = [np.asarray(oracle["data"][f"demo_{i}"]["expert_phase"]) for i in range(len(ds.trajs))]
        if [len(p) for p in phases] != [len(t.acts) for t in ds.trajs]:
            raise SystemExit(f"{source}: the oracle's phases do not line up with the imported demonstrations")
        # a label per observation: the last one, after the last action, keeps the last action's phase
        labelled = [dataclasses.replace(t, subtasks=merge_short_runs(np.append(p, p[-1]), MIN_SEGMENT))
                    for t, p in zip(ds.trajs, phases, strict=True)]
        write_dataset(labelled, folder, ds.env_id, f"segbench/{name}-v0",
                      description=f"robosuite {ROBOSUITE[name]}: the scripted expert's phases",
                      observation_space=ds.observation_space, action_space=ds.action_space)
    trajs = load_dataset(folder).trajs
    labels = np.concatenate([np.asarray(t.subtasks) for t in trajs])
    codes = len(np.unique(labels))
    return folder, codes, (f"robosuite {ROBOSUITE[name]}: the scripted expert's {codes} phases (tests/data/robosuite "
                           f"fixture, {len(trajs)} episodes, {len(labels) - len(trajs)} steps)")


def _command_path(folder: Path) -> str:
    """`folder` as the recorded commands name it: relative to the working directory (the repository's root) when it
    lies below it, so a published command runs on any checkout."""
    try:
        return folder.resolve().relative_to(Path.cwd().resolve()).as_posix()
    except ValueError:
        return str(folder)


def task_data(name: str, data_root: Path) -> tuple[str, int, bool, str]:
    """(demos, K, shipped, description) of task `name`, recording a course's data set first if needed."""
    if name.startswith("metaworld-"):
        folder, codes, description = metaworld_dataset(name, data_root)
        return _command_path(folder), codes, True, description
    if name in ROBOSUITE:
        folder, codes, description = robosuite_dataset(name, data_root)
        return _command_path(folder), codes, True, description
    if name in COURSES:
        folder = record_course(name, data_root, seed=0)
        return _command_path(folder), COURSES[name].codes, False, COURSES[name].description
    if name in DERIVED:
        return (_command_path(derived_dataset(name, data_root)), DERIVED[name]["codes"], True,
                DERIVED[name]["description"])
    spec = SHIPPED[name]
    return spec["demos"], spec["codes"], True, spec["description"]


def _cpu_seconds() -> float:
    """CPU time of this process and its finished children, every thread (what a shared machine does not inflate)."""
    import resource

    own, kids = resource.getrusage(resource.RUSAGE_SELF), resource.getrusage(resource.RUSAGE_CHILDREN)
    return own.ru_utime + own.ru_stime + kids.ru_utime + kids.ru_stime


def run_one(name: str, seed: int, runs: Path, data_root: Path, extra: list[str]) -> dict[str, Any]:
    demos, codes, shipped, _ = task_data(name, data_root)
    run = runs / f"{name}_s{seed}"
    pretrain = ["pretrain", "--demos", demos, "--codes", str(codes), "--seed", str(seed), "--out", str(run),
                "--force", *(["--preset", "default"] if shipped else []), *extra]
    print("$ digail " + shlex.join(pretrain), flush=True)
    t0, cpu0 = time.perf_counter(), _cpu_seconds()
    if digail(pretrain) != 0:
        raise SystemExit(f"digail pretrain failed on {name} seed {seed}")
    elapsed, cpu = time.perf_counter() - t0, _cpu_seconds() - cpu0
    if digail(["segment", str(run)]) != 0:
        raise SystemExit(f"digail segment failed on {name} seed {seed}")
    seg = json.loads((run / "segmentation.json").read_text())
    config = json.loads((run / "config.json").read_text())
    row = {k: seg[k] for k in KEYS if k in seg}
    row.update(reading=seg.get("reading", "causal"), boundary_f1_5=seg.get("boundary_f1_5"),
               readings=seg.get("readings", {}))
    row.update(time_s=round(elapsed, 1), cpu_s=round(cpu, 1), seed=seed, steps=seg["steps"], episodes=seg["episodes"],
               epochs=config["vae"].get("epochs_run", config["vae"]["epochs"]),
               command=f"digail {shlex.join(pretrain)}")
    if "restarts" in config:
        row["restarts"] = config["restarts"]
    return row


def extra_flags(args: argparse.Namespace) -> list[str]:
    """`--set FIELD=VALUE ...` as `digail pretrain` flags."""
    return [part for item in args.set for part in (f"--{item.split('=', 1)[0]}", *item.split("=", 1)[1].split())]


def summarize(rows: list[dict[str, Any]]) -> dict[str, Any]:
    out: dict[str, Any] = {k: float(np.median([r[k] for r in rows])) for k in KEYS
                           if all(r.get(k) is not None for r in rows)}
    readings = {name for r in rows for name in r.get("readings", {})}
    if readings and all(set(r.get("readings", {})) == readings for r in rows):
        # both readings' medians, the causal (the paper's q) and the offline one (for annotations)
        out["readings"] = {name: {k: float(np.median([r["readings"][name][k] for r in rows]))
                                  for k in rows[0]["readings"][name]} for name in sorted(readings)}
    return out


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--tasks", nargs="+", default=task_names(), choices=task_names())
    parser.add_argument("--seeds", nargs="+", type=int, default=[0, 1, 2])
    parser.add_argument("--out", type=Path, default=HERE / "results" / "segmentation" / "segmentation.json")
    parser.add_argument("--runs", type=Path, default=Path("runs/segbench"))
    parser.add_argument("--data", type=Path, default=Path("runs/segbench/datasets"))
    parser.add_argument("--set", nargs="*", default=[], metavar="FIELD=VALUE",
                        help="extra `digail pretrain` flags for every task, e.g. vae.smoothing-weight=0.3")
    parser.add_argument("--measure", choices=["table", "restarts", "codes", "figure", "codes-figure"],
                        default="table")
    parser.add_argument("--restarts", type=int, default=3, help="restarts per (task, seed) with --measure restarts")
    parser.add_argument("--merge", nargs="+", type=Path, metavar="JSON",
                        help="join table files of separate calls (other tasks or seeds) into --out, medians anew")
    parser.add_argument("--curve-only", action="store_true",
                        help="--measure codes: only the K curve and the choice, without training the chosen K")
    args = parser.parse_args(argv)
    os.environ.setdefault("MUJOCO_GL", "egl")
    extra = extra_flags(args)
    if args.merge:
        merge(args.merge, args.out)
        return
    if args.measure == "codes-figure":
        from digail.viz.figures import codes_curve

        tasks = json.loads(args.out.read_text())["tasks"]
        codes_curve({f"{name} seed 0": [{**c, "chosen": c["codes"] == t["seeds"][0]["chosen"]}
                                        for c in t["seeds"][0]["curve"]] for name, t in tasks.items()},
                    HERE / "results" / "figures" / "segmentation_codes.png",
                    truth={f"{name} seed 0": t["seeds"][0]["true_codes"] for name, t in tasks.items()})
        return
    if args.measure == "figure":
        figure(args.out, args.runs, args.data, HERE / "results" / "figures" / "segmentation_benchmark.png")
        return
    if args.measure != "table":
        out = args.out.with_name(f"segmentation_{args.measure}.json") if args.out.name == "segmentation.json" \
            else args.out
        measure(args, out)
        return
    result: dict[str, Any] = {"command": "python benchmarks/segmentation.py " + shlex.join(sys.argv[1:] if argv is None
                                                                                           else argv),
                              "settings": extra, "tasks": {}}
    if args.out.exists():  # keep tasks of an earlier call that this one does not run
        old = json.loads(args.out.read_text())
        if old.get("settings") == extra:
            result["tasks"] = old.get("tasks", {})
    for name in args.tasks:
        rows = [run_one(name, s, args.runs, args.data, extra) for s in args.seeds]
        _, codes, _, description = task_data(name, args.data)
        result["tasks"][name] = {"description": description, "codes": codes, "seeds": rows,
                                 "median": summarize(rows)}
        med = result["tasks"][name]["median"]
        print(f"== {name}: accuracy {med['accuracy']:.3f}  NMI {med['nmi']:.3f}  F1 {med['boundary_f1']:.3f}  "
              f"switches {med['switches_per_episode']:.2f} (truth {med['true_switches_per_episode']:.2f})  "
              f"{med['time_s']:.0f} s", flush=True)
        args.out.parent.mkdir(parents=True, exist_ok=True)
        args.out.write_text(json.dumps(result, indent=1) + "\n")
    print(table(result))


def merge(parts: list[Path], out: Path) -> None:
    """Join the table files `parts` (calls that ran other tasks or other seeds with the same settings) into `out`:
    each task's seeds together, its medians computed anew, every call's command kept."""
    result: dict[str, Any] = {"commands": [], "settings": None, "tasks": {}}
    for part in parts:
        data = json.loads(part.read_text())
        if result["settings"] is not None and data.get("settings") != result["settings"]:
            raise SystemExit(f"{part} was run with other settings ({data.get('settings')}); merge like with like.")
        result["settings"] = data.get("settings")
        result["commands"].append(data["command"])
        for name, task in data["tasks"].items():
            into = result["tasks"].setdefault(name, {k: v for k, v in task.items() if k not in ("seeds", "median")})
            seeds = {r["seed"]: r for r in into.get("seeds", [])}
            seeds.update({r["seed"]: r for r in task["seeds"]})
            into["seeds"] = [seeds[k] for k in sorted(seeds)]
            into["median"] = summarize(into["seeds"])
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(json.dumps(result, indent=1) + "\n")
    print(table(result))


def figure(results: Path, runs: Path, data_root: Path, out: Path, episodes: int = 3) -> None:
    """One panel per task of `results`: for the first `episodes` demonstrations, the oracle labels (upper strip)
    and the seed-0 run's codes (lower strip), each code drawn in the colour of the label it is matched to."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from digail.data.minari_io import load_dataset

    tasks = json.loads(results.read_text())["tasks"]
    cols = 2
    rows = -(-len(tasks) // cols)
    fig, axes = plt.subplots(rows, cols, figsize=(12, 1.55 * rows), squeeze=False)
    cmap = matplotlib.colormaps["tab10"]
    for ax, (name, task) in zip(axes.flat, tasks.items(), strict=False):
        demos, _, _, _ = task_data(name, data_root)
        labels = [np.asarray(t.subtasks)[:len(t)] for t in load_dataset(demos).trajs[:episodes]]
        run = runs / f"{name}_s0"
        codes = np.load(run / "codes.npz", allow_pickle=False)
        mapping = {int(k): int(v) for k, v in json.loads((run / "segmentation.json").read_text())["mapping"].items()}
        width = max(len(c) for c in labels)
        strips = []
        for i, truth in enumerate(labels):
            found = np.array([mapping.get(int(c), 9) for c in codes[f"episode_{i:05d}"][:len(truth)]])
            for row in (truth, found):
                strips.append(np.r_[row, np.full(width - len(row), -1)].astype(float))
            strips.append(np.full(width, -1.0))  # a gap between episodes
        img = np.ma.masked_less(np.array(strips[:-1]), 0)
        ax.imshow(img, aspect="auto", cmap=cmap, vmin=0, vmax=9, interpolation="nearest")
        ax.set_yticks([3 * i + j for i in range(len(labels)) for j in (0, 1)],
                      [f"ep {i} {what}" for i in range(len(labels)) for what in ("truth", "codes")], fontsize=7)
        ax.tick_params(axis="x", labelsize=7)
        med = task["median"]
        ax.set_title(f"{name} (K = {task['codes']}): median accuracy {med['accuracy']:.3f}, "
                     f"{med['switches_per_episode']:.2f} switches / episode (truth "
                     f"{med['true_switches_per_episode']:.2f})", fontsize=8)
    for ax in axes.flat[len(tasks):]:
        ax.axis("off")
    axes.flat[-1].set_xlabel("step", fontsize=7)
    fig.suptitle("Segmentation benchmark with the defaults, seed 0: oracle labels against the codes (colour = the "
                 "label a code is matched to)", fontsize=9)
    fig.tight_layout()
    out.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(out, dpi=110)
    print(f"wrote {out}")


def measure(args: argparse.Namespace, out: Path) -> None:
    """`--measure restarts` or `--measure codes` (module docstring)."""

    from digail.algos.decode import segment_many
    from digail.algos.model_selection import description_length, heldout_split
    from digail.algos.vae_pretrain import codes_curve, pretrain
    from digail.config import VAEConfig
    from digail.data.minari_io import load_dataset
    from digail.eval.segmentation import segmentation_metrics
    from digail.nets.policy import ActionSpec
    from digail.utils import set_torch_threads

    set_torch_threads(1)
    argv = sys.argv[1:]
    result: dict[str, Any] = {"command": "python benchmarks/segmentation.py " + shlex.join(argv), "tasks": {}}
    if out.exists():
        result["tasks"] = json.loads(out.read_text()).get("tasks", {})
    for name in args.tasks:
        demos, codes, shipped, _ = task_data(name, args.data)
        rows = []
        for seed in args.seeds:
            if args.measure == "codes" and args.curve_only:
                # the K `--codes auto` chooses (`vae_pretrain.codes_curve`, what `select_codes` decides by),
                # without training the chosen K's VAE afterwards
                ds = load_dataset(demos)
                cfg = VAEConfig()
                for item in args.set:  # vae.FIELD=VALUE, cast to the field's current type
                    key, value = item.split("=", 1)
                    field = key.removeprefix("vae.").replace("-", "_")
                    cast = float if getattr(cfg, field) is None else type(getattr(cfg, field))
                    cfg = dataclasses.replace(cfg, **{field: cast(value)})
                discrete = ActionSpec.from_space(ds.action_space).discrete
                t0 = time.perf_counter()
                curve, pick = codes_curve(ds.trajs, cfg, list(range(2, 9)), discrete, seed=seed)
                chosen = int(curve[pick]["chosen_codes"])
                truth = len(np.unique(np.concatenate([t.subtasks for t in ds.trajs])))
                rows.append({"seed": seed, "true_codes": truth, "chosen": chosen, "hit": chosen == truth,
                             "criterion": cfg.k_criterion, "curve": curve,
                             "time_s": round(time.perf_counter() - t0, 1)})
                print(f"== {name} seed {seed}: K = {chosen} (true {truth}) "
                      + " ".join(f"{c['dl_per_step']:.3f}" for c in curve), flush=True)
            elif args.measure == "codes":
                run = args.runs / f"{name}_auto_s{seed}"
                cmd = ["pretrain", "--demos", demos, "--codes", "auto", "--seed", str(seed), "--out", str(run),
                       "--force", *(["--preset", "default"] if shipped else []), *extra_flags(args)]
                print("$ digail " + shlex.join(cmd), flush=True)
                t0 = time.perf_counter()
                if digail(cmd) != 0:
                    raise SystemExit(f"digail pretrain --codes auto failed on {name} seed {seed}")
                config = json.loads((run / "config.json").read_text())
                chosen = int(config["vae"]["codes"])
                # the truth is the number of distinct oracle labels (Four Rooms: 4 corridors and the apple)
                truth = len(np.unique(np.concatenate([t.subtasks for t in load_dataset(demos).trajs])))
                rows.append({"seed": seed, "true_codes": truth, "chosen": chosen, "hit": chosen == truth,
                             "criterion": config["vae"]["k_criterion"], "curve": config["k_selection"],
                             "time_s": round(time.perf_counter() - t0, 1)})
                print(f"== {name} seed {seed}: K = {chosen} (true {truth})", flush=True)
            else:
                ds = load_dataset(demos)
                cfg = dataclasses.replace(VAEConfig(), codes=codes)
                train, held = heldout_split(len(ds.trajs), cfg.heldout_fraction, seed)
                fit_on, held_out = [ds.trajs[i] for i in train], [ds.trajs[i] for i in held]
                labels = [t.subtasks for t in ds.trajs]
                restarts = []
                for r in range(args.restarts):
                    model, _ = pretrain(fit_on, cfg, action_spec=ActionSpec.from_space(ds.action_space),
                                        seed=seed + r, progress=False)
                    m = segmentation_metrics(segment_many(model, ds.trajs), labels)
                    restarts.append({"seed": seed + r, **description_length(model, held_out),
                                     "accuracy": m["accuracy"], "switches_per_episode": m["switches_per_episode"]})
                pick = min(range(len(restarts)), key=lambda i: restarts[i]["dl_per_step"])
                best = max(r["accuracy"] for r in restarts)
                rows.append({"seed": seed, "restarts": restarts, "chosen": restarts[pick]["seed"],
                             "chosen_accuracy": restarts[pick]["accuracy"], "best_accuracy": best,
                             "hit": restarts[pick]["accuracy"] >= best - 1e-9})
                print(f"== {name} seed {seed}: chosen accuracy {restarts[pick]['accuracy']:.3f}, best {best:.3f}",
                      flush=True)
        result["tasks"][name] = {"codes": codes, "seeds": rows, "hits": sum(r["hit"] for r in rows),
                                 "of": len(rows), "command": result["command"]}
        out.parent.mkdir(parents=True, exist_ok=True)
        out.write_text(json.dumps(result, indent=1) + "\n")


def table(result: dict[str, Any]) -> str:
    lines = ["| task | K | accuracy | NMI | boundary F1 (±2 / ±5) | causal reading: accuracy, F1 ±5 | "
             "switches / episode (truth) | time |",
             "| --- | --- | --- | --- | --- | --- | --- | --- |"]
    for name, task in result["tasks"].items():
        m = task["median"]
        accs = " / ".join(f"{r['accuracy']:.2f}" for r in task["seeds"])
        f1_5 = f" / {m['boundary_f1_5']:.2f}" if "boundary_f1_5" in m else ""
        causal = m.get("readings", {}).get("causal")
        causal_cell = f"{causal['accuracy']:.3f}, {causal['boundary_f1_5']:.2f}" if causal else "-"
        lines.append(f"| {name} | {task['codes']} | {m['accuracy']:.3f} ({accs}) | {m['nmi']:.2f} | "
                     f"{m['boundary_f1']:.2f}{f1_5} | {causal_cell} | {m['switches_per_episode']:.2f} "
                     f"({m['true_switches_per_episode']:.2f}) | {m['time_s']:.0f} s |")
    return "\n".join(lines)


if __name__ == "__main__":
    main()
