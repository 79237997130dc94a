"""From a spec to jobs: every trial's stages as `digail` command lines, with one shared VAE per (env, seed).

Paths in the command lines are relative to the sweep folder, where every stage runs, so the recorded commands read
as `cd SWEEP && digail ...` and a sweep folder can be moved (or mounted elsewhere on a cluster's nodes).

Layout of a sweep folder:

    SWEEP/<env>/vae_s<seed>/            a VAE (pre-trained once, shared by the (env, seed)'s trials)
    SWEEP/<env>/<method>_s<seed>/       a trained policy; the `vae` method evaluates the VAE's folder instead
    SWEEP/trials/<job>.json             each job's state: attempts, stages done, their commands and wall times
    SWEEP/logs/<job>.log                the stages' output
    SWEEP/results.json, results.md      the tables (`digail sweep --summarize SWEEP`)

A run folder's name gains `__key=value` parts only where two trials of one (env, method, seed) differ.
"""

from __future__ import annotations

import itertools
from dataclasses import dataclass, field
from typing import Any

from digail.errors import UserError
from digail.sweep.spec import METHODS, Range, SweepSpec, Value

VAE_KEYS = ("vae.", "pretrain.")
DEMO_KEYS = "demos."
"""the demonstration subset (`demos.episodes`, `demos.subsample`): the VAE's and the training's"""
"""override prefixes that change the VAE (and so which VAE a trial shares)"""


@dataclass(frozen=True)
class Stage:
    """One `digail` command of a job."""

    name: str
    """pretrain, train, evaluate, segment or compose"""
    argv: tuple[str, ...]
    """arguments after `digail`"""
    resume: tuple[str, ...] | None = None
    """arguments that continue this stage after a kill when its run folder holds a checkpoint (train)"""
    run: str = ""
    """run folder the stage writes (relative to the sweep folder)"""
    labels: str | None = None
    """compose: the schedule in oracle labels ('label:steps,...'), put into the argv's '{schedule}' in code ids
    by the segmentation `mapping` of the VAE in `mapping_from`"""
    mapping_from: str = ""
    """compose: the VAE run folder whose segmentation maps codes to labels"""


@dataclass(frozen=True)
class Job:
    """A unit that Ray schedules: a VAE pre-training, or one trial's remaining stages."""

    id: str
    """unique name, `<env>/<run folder name>` (a VAE job: `<env>/pretrain_s<seed>...`)"""
    kind: str
    """'vae' (pre-training, shared) or 'trial'"""
    env: str
    """environment id"""
    method: str
    """method name (a VAE job: 'pretrain')"""
    seed: int
    """seed"""
    run: str
    """the trial's run folder, relative to the sweep folder"""
    stages: tuple[Stage, ...]
    """commands in order"""
    deps: tuple[str, ...] = ()
    """ids of jobs that must finish first (the VAE)"""
    settings: dict[str, Any] = field(default_factory=dict)
    """preset, demos, episodes and override values of this trial: what tells it apart from its neighbours"""
    label: str = ""
    """the row of the results table: the method plus any setting that varies between the env's trials"""

    @property
    def file_id(self) -> str:
        """`id` made safe as a file name"""
        return self.id.replace("/", "__")


def env_dir(env_id: str) -> str:
    """Folder name of an env inside a sweep: the id with '/' made safe."""
    return env_id.replace("/", "-")


def flag_name(key: str) -> str:
    """`--vae.kl-weight` for key vae.kl_weight; stage-own keys (pretrain.codes) lose their prefix."""
    head, _, rest = key.partition(".")
    if head in ("pretrain", "evaluate", "segment"):
        return "--" + rest.replace("_", "-")
    if head == "demos":
        return "--demos-" + rest.replace("_", "-")
    return "--" + key.replace("_", "-")


def flag_args(key: str, value: Value) -> list[str]:
    """Command-line arguments setting `key` to `value` (tyro: booleans as --x / --no-x, tuples spread)."""
    name = flag_name(key)
    if isinstance(value, bool):
        if value:
            return [name]
        head, _, last = name.rpartition(".")
        return [f"{head}.no-{last}" if head else "--no-" + name[2:]]
    if value is None:
        return [name, "None"]
    if isinstance(value, tuple):
        return [name, *(str(v) for v in value)]
    return [name, str(value)]


def value_text(value: Value | Range) -> str:
    """A value as written in tags and tables."""
    if isinstance(value, tuple):
        return " ".join(str(v) for v in value)
    return str(value)


def expand(spec: SweepSpec, *, allow_ranges: bool = False) -> list[dict[str, Any]]:
    """Every trial of the spec as (env, method, seed, settings) records, duplicates removed, in grid order."""
    out: list[dict[str, Any]] = []
    for grid in spec.grids:
        keys = [k for k, _ in grid.overrides]
        for values in itertools.product(*(vals for _, vals in grid.overrides)):
            if not allow_ranges and any(isinstance(v, Range) for v in values):
                raise UserError("an override is a range (LOW..HIGH); ranges are searched: add --search optuna, "
                                "or give values as V1,V2.")
            overrides = dict(zip(keys, values, strict=True))
            for env, seed, method in itertools.product(grid.envs, grid.seeds, grid.methods):
                settings: dict[str, Any] = {"preset": grid.preset, "demos": grid.demos or _default_demos(env),
                                            "episodes": grid.episodes, "compose": grid.compose, **overrides}
                if METHODS[method][1] and "train.bc_weight" not in settings:
                    settings["train.bc_weight"] = grid.bc_weight
                # what a method never reads does not make it another trial: the VAE baseline trains nothing,
                # GAIL uses no VAE
                unused = ("train.", "segment.") if METHODS[method][0] is None else (
                    VAE_KEYS if METHODS[method][0] == "gail" else ())
                settings = {k: v for k, v in settings.items() if not (unused and k.startswith(unused))}
                out.append({"env": env, "method": method, "seed": int(seed), "settings": settings})
    return _unique(out)


def _unique(records: list[dict[str, Any]]) -> list[dict[str, Any]]:
    """`records` without repeats (the same trial asked for twice), in order."""
    seen: set[str] = set()
    out = []
    for rec in records:
        ident = repr((rec["env"], rec["method"], rec["seed"], sorted((k, repr(v)) for k, v in rec["settings"].items())))
        if ident not in seen:
            seen.add(ident)
            out.append(rec)
    return out


def _default_demos(env_id: str) -> str:
    from digail.data.demos import default_dataset_id

    return default_dataset_id(env_id)


def _default_episodes(preset: str | None, env_id: str) -> int:
    from digail.envs.registry import preset_for

    return preset_for(env_id, preset).eval_episodes


def _differing(records: list[dict[str, Any]], keys: list[str] | None = None) -> list[str]:
    """Setting keys whose values differ between `records` (in a stable order)."""
    all_keys = sorted({k for r in records for k in r["settings"]} if keys is None else keys)
    return [k for k in all_keys if len({repr(r["settings"].get(k)) for r in records}) > 1]


def _tag(settings: dict[str, Any], keys: list[str]) -> str:
    return "".join(f"__{k}={value_text(settings.get(k))}".replace("/", "-").replace(" ", "-") for k in keys)


def plan(spec: SweepSpec, records: list[dict[str, Any]] | None = None, always_tag: tuple[str, ...] = ()) -> list[Job]:
    """Jobs for every trial of `spec` (or of the given expanded `records`): VAE jobs first, then the trials.

    `always_tag`: setting keys named in every run folder that has them (a search's sampled keys), not only where
    trials collide."""
    records = _unique(expand(spec) if records is None else records)
    # a trial that declares GPUs runs its VAE and trainer on one (config.json records the device)
    device = ["--device", "cuda"] if spec.gpus_per_trial > 0 else []
    vae_jobs: dict[str, Job] = {}
    jobs: list[Job] = []

    def vae_settings(rec: dict[str, Any]) -> dict[str, Any]:
        return {k: v for k, v in rec["settings"].items()
                if k in ("preset", "demos") or k.startswith((*VAE_KEYS, DEMO_KEYS))}

    # names: a suffix only where trials (or VAEs) of one (env, method, seed) differ
    by_base: dict[tuple[str, str, int], list[dict[str, Any]]] = {}
    for rec in records:
        by_base.setdefault((rec["env"], rec["method"], rec["seed"]), []).append(rec)
    vae_groups: dict[tuple[str, int], list[dict[str, Any]]] = {}
    for rec in records:
        if METHODS[rec["method"]][0] != "gail":
            vae_groups.setdefault((rec["env"], rec["seed"]), []).append({"settings": vae_settings(rec)})
    by_env_method: dict[tuple[str, str], list[dict[str, Any]]] = {}
    for rec in records:
        by_env_method.setdefault((rec["env"], rec["method"]), []).append(rec)

    for rec in records:
        env, method, seed, settings = rec["env"], rec["method"], rec["seed"], rec["settings"]
        train_method, _ = METHODS[method]
        edir = env_dir(env)
        preset = ["--preset", settings["preset"]] if settings["preset"] else []
        vae_run = None
        deps: tuple[str, ...] = ()
        if train_method != "gail":
            vs = vae_settings(rec)
            vtag = _tag(vs, sorted({*_differing(vae_groups[(env, seed)]), *(k for k in always_tag if k in vs)}))
            vae_run = f"{edir}/vae_s{seed}{vtag}"
            vid = f"{edir}/pretrain_s{seed}{vtag}"
            if vid not in vae_jobs:
                argv = ["pretrain", "--demos", settings["demos"], "--seed", str(seed), "--out", vae_run, "--force",
                        *preset, *device]
                for key, value in sorted(vs.items()):
                    if key.startswith((*VAE_KEYS, DEMO_KEYS)):
                        argv += flag_args(key, value)
                vae_jobs[vid] = Job(id=vid, kind="vae", env=env, method="pretrain", seed=seed, run=vae_run,
                                    stages=(Stage("pretrain", tuple(argv), run=vae_run),), settings=vs,
                                    label="pretrain")
            deps = (vid,)
        keys = sorted({*_differing(by_base[(env, method, seed)]), *(k for k in always_tag if k in settings)})
        name = f"{method}_s{seed}{_tag(settings, keys)}"
        episodes = settings["episodes"] or _default_episodes(settings["preset"], env)
        eval_extra = [a for k, v in sorted(settings.items()) if k.startswith("evaluate.") for a in flag_args(k, v)]
        seg_extra = [a for k, v in sorted(settings.items()) if k.startswith("segment.") for a in flag_args(k, v)]
        stages: list[Stage] = []
        if train_method is None:
            assert vae_run is not None
            run = vae_run
        else:
            run = f"{edir}/{name}"
            argv = ["train", "--method", train_method, "--demos", settings["demos"], "--seed", str(seed),
                    "--out", run, "--force", *preset, *device]
            if vae_run is not None:
                argv += ["--vae", vae_run]
            for key, value in sorted(settings.items()):
                if key.startswith(("train.", DEMO_KEYS)):
                    argv += flag_args(key, value)
            stages.append(Stage("train", tuple(argv), resume=("train", "--resume", run), run=run))
        stages.append(Stage("evaluate", ("evaluate", run, "--episodes", str(episodes), *eval_extra), run=run))
        if train_method is not None:
            stages.append(Stage("segment", ("segment", run, *seg_extra), run=run))
        if settings.get("compose"):
            assert vae_run is not None, "compose needs a VAE's segmentation"
            stages.append(Stage("compose", ("compose", run, "--schedule", "{schedule}", "--episodes", "100"),
                                run=run, labels=settings["compose"], mapping_from=vae_run))
        label_keys = sorted({*_differing(by_env_method[(env, method)]), *(k for k in always_tag if k in settings)}
                            - {"compose"})
        label = method + (" [" + ", ".join(f"{k}={value_text(settings.get(k))}" for k in label_keys) + "]"
                          if label_keys else "")
        jobs.append(Job(id=f"{edir}/{name}", kind="trial", env=env, method=method, seed=seed, run=run,
                        stages=tuple(stages), deps=deps, settings=settings, label=label))
    ids = [j.id for j in jobs]
    if len(set(ids)) != len(ids):  # settings that differ only in ways the names cannot show
        raise UserError("two trials of the sweep would share a run folder; make their grids differ in an override.")
    return [*vae_jobs.values(), *jobs]

