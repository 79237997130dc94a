"""`digail generate --demos D --out O`: new demonstrations in new scenes from the sub-tasks of a few (MimicGen's
recipe: `digail.algos.generate`), written as a Minari dataset."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any, Literal

from digail.checks import check_episodes
from digail.config import check_at_least, check_seed
from digail.errors import UserError

GENERATION_SEED = 1_000_000
"""default seed of the first attempt: clear of the demonstrations' (0 up) and the final evaluations' (10,000 up)"""


@dataclass(frozen=True)
class GenerateArgs:
    """Generate demonstrations in new scenes by replaying each source sub-task's end-effector path in its object's or
    goal's frame; the attempts that reach the env's success are written as a Minari dataset."""

    demos: str
    """source demonstrations: a dataset folder or id, e.g. digail/fetchpickandplace/expert-v0"""
    out: Path
    """the dataset folder to write, or with --format robomimic the .hdf5 file (never replaced; an unfinished run's
    progress waits beside it in OUT.partial)"""
    format: Literal["minari", "robomimic"] = "minari"
    """what to write: a Minari dataset, or a robomimic HDF5 file whose demonstrations carry their sub-tasks as
    MimicGen termination signals (datagen_info/subtask_term_signals/subtask_<i>)"""
    segments: Literal["labels", "codes", "one", "chunks"] = "labels"
    """where the sub-tasks come from: `labels` the dataset's oracle sub-task labels, `codes` a pre-trained run's
    codes (--vae or --codes), `one` the whole demonstration as one sub-task in the object's frame, `chunks` pieces
    of --chunk steps"""
    vae: Path | None = None
    """--segments codes: a pre-trained run folder; its codes.npz (what `digail segment` wrote) where it covers the
    sources, else the run's model segments them causally"""
    codes: Path | None = None
    """--segments codes: a codes.npz of the dataset's episodes (one array per episode, in order) instead of --vae"""
    chunk: int = 10
    """--segments chunks: steps per piece"""
    min_segment: int = 3
    """runs of a label or code shorter than this (steps) are merged into a neighbour (one-step flickers)"""
    sources: str | None = None
    """episode indices of the dataset to generate from, e.g. '0' or '0,1,2,3' (default: every episode)"""
    frames: str | None = None
    """each sub-task's reference frame, in the order of the sub-task ids, e.g. object,object,goal,goal (default:
    inferred: the frame in which its end pose is most consistent across the sources, or the nearest at its end with
    one source)"""
    frame_trials: int = 0
    """before generating, choose each sub-task's frame in the simulator: starting from the inferred frames, each
    sub-task in turn tries every other frame on this many scenes (their own reset seeds, after the attempts') and
    keeps the frame whose attempts succeed most often (0: the inferred frames as they are)"""
    order: str | None = None
    """the sub-task ids to chain, e.g. 3,2,1,0 (default: each source's own order); a source's first segment of each
    id is played"""
    attempts: int = 100
    """attempts to play at most"""
    successes: int | None = None
    """stop once this many demonstrations are kept (default: play every attempt)"""
    seed: int = GENERATION_SEED
    """attempt i resets the env with seed + i"""
    pick: Literal["cycle", "nearest", "first", "best"] = "cycle"
    """which source an attempt replays: `cycle` source i mod the number of sources, `nearest` the source whose
    object (and goal) started nearest to the new scene's, so that one scene always comes with one way of doing the
    task, `first` always the first source, the others only informing the frames (one way for every scene), or
    `best` always the source whose trial attempts succeed most often (each source on --frame-trials scenes, its
    frames chosen there, or on 20 scenes with the inferred frames)"""
    gain: float = 1.0
    """share of the end-effector's position error the move actions correct in one step (clipped to the bounds)"""
    blend: int = 5
    """steps over which the gap between the end-effector and a sub-task's moved path closes"""
    hold: int = 10
    """steps the path's last point is held after it while the env has not yet succeeded"""
    interp_speed: float = 1.0
    """before a sub-task whose moved path starts away from the end-effector, a straight move there at this many
    action units per step (1: the action bound; 0: none, the gap closes over --blend steps instead)"""
    env: str | None = None
    """the env to generate in (default: the dataset's)"""
    env_arg: tuple[str, ...] = ()
    """KEY=VALUE keyword arguments for the env, e.g. order=3,2,1,0 for the landmark route driven in a new order
    (recorded in the dataset's env spec)"""
    ee: str | None = None
    """an env without registry columns: the end-effector position's observation columns, e.g. 0:3"""
    object: str | None = None
    """an env without registry columns: the object position's observation columns"""
    goal: str | None = None
    """an env without registry columns: the goal position's observation columns (optional)"""
    move_actions: str | None = None
    """an env without registry columns: the action columns that displace the end-effector, e.g. 0:3"""
    gripper_action: int | None = None
    """an env without registry columns: the gripper's action column (kept from the source)"""
    action_scale: float | None = None
    """an env without registry columns: metres the end-effector moves per action unit"""
    dataset_id: str | None = None
    """Minari id stored in the dataset (default: digail/<env name>/generated-v0)"""
    progress: bool = True
    """show a progress bar"""

    @property
    def trial_scenes(self) -> int:
        """scenes the trials play before the attempts (their reset seeds follow the attempts')"""
        from digail.algos.trials import PICK_TRIALS

        return PICK_TRIALS if self.pick == "best" and not self.frame_trials else self.frame_trials

    def __post_init__(self) -> None:
        check_episodes(self.attempts, "--attempts")  # each attempt an episode, each kept one held until written
        check_episodes(self.successes, "--successes")
        check_at_least(self.chunk, "--chunk")
        check_at_least(self.min_segment, "--min-segment")
        check_at_least(self.blend, "--blend")
        check_at_least(self.hold, "--hold", low=0)
        check_at_least(self.frame_trials, "--frame-trials", low=0)
        check_seed(self.seed, count=self.attempts + self.trial_scenes, count_flag="--attempts")
        if self.frame_trials and self.frames is not None:
            raise UserError("--frames names the frames and --frame-trials chooses them; pass one of the two.")
        if not 0 <= self.interp_speed <= 1:
            raise UserError(f"--interp-speed must be in [0, 1] (action units per step), not {self.interp_speed}.")
        if not 0 < self.gain <= 2:
            raise UserError(f"--gain must be in (0, 2] (the share of the error corrected per step), not {self.gain}.")
        if self.env_arg:
            from digail.envs.registry import parse_env_args

            parse_env_args(self.env_arg)  # a malformed one is refused before any work
        if self.format == "robomimic" and self.out.suffix not in (".hdf5", ".h5"):
            raise UserError(f"--format robomimic writes one HDF5 file; name --out with .hdf5, e.g. "
                            f"{self.out.with_suffix('.hdf5')}.")
        if self.segments == "codes" and (self.vae is None) == (self.codes is None):
            raise UserError("--segments codes reads the codes of a pre-trained run; pass --vae RUN or --codes FILE "
                            "(one of them).")
        if self.segments != "codes" and (self.vae is not None or self.codes is not None):
            raise UserError(f"--vae and --codes give codes, which --segments {self.segments} does not use; pass "
                            "--segments codes or drop them.")


def _scene(args: GenerateArgs, env_id: str) -> Any:
    """The env's columns: its registry entry's, or the user's flags (all of them), refused in one sentence."""
    from digail.envs.registry import env_spec
    from digail.envs.scene import SceneColumns, parse_columns

    flags = {"--ee": args.ee, "--object": args.object, "--move-actions": args.move_actions,
             "--action-scale": args.action_scale}
    given = [k for k, v in flags.items() if v is not None]
    if given or args.goal is not None or args.gripper_action is not None:
        missing = [k for k, v in flags.items() if v is None]
        if missing:
            raise UserError(f"naming the scene's columns needs {', '.join(missing)} as well; pass every one of "
                            "--ee, --object, --move-actions and --action-scale (--goal and --gripper-action if any).")
        return SceneColumns(ee=parse_columns(str(args.ee), "--ee"), object=parse_columns(str(args.object),
                            "--object"), goal=None if args.goal is None else parse_columns(args.goal, "--goal"),
                            move_actions=parse_columns(str(args.move_actions), "--move-actions"),
                            gripper_action=args.gripper_action, action_scale=float(args.action_scale or 0.0))
    spec = env_spec(env_id)
    if spec is None or spec.scene is None:
        raise UserError(f"{env_id} does not say where its end-effector, object and goal are in the observation; "
                        "name them with --ee, --object, --goal, --move-actions, --gripper-action and "
                        "--action-scale.")
    return spec.scene


def _source_ids(text: str | None, count: int) -> list[int]:
    if text is None:
        return list(range(count))
    try:
        ids = [int(x) for x in text.split(",") if x.strip()]
    except ValueError:
        raise UserError(f"--sources {text!r} is not a list of episode indices; pass e.g. 0,1,2.") from None
    bad = [i for i in ids if not 0 <= i < count]
    if not ids or bad or len(set(ids)) != len(ids):
        raise UserError(f"--sources {text!r} must name distinct episodes of the dataset's {count} (0-{count - 1}).")
    return ids


def _codes(args: GenerateArgs, trajs: list[Any], ids: list[int]) -> list[Any]:
    """Per-step codes of the source episodes: from --codes or the run's codes.npz where they cover them, else the
    run's model segments them."""
    import numpy as np

    def read(path: Path) -> list[np.ndarray] | None:
        try:
            with np.load(path, allow_pickle=False) as z:
                return [np.asarray(z[k], np.int64) for k in sorted(z.files)]
        except (OSError, ValueError):
            return None

    def covers(codes: list[np.ndarray] | None) -> bool:
        return codes is not None and all(i < len(codes) and len(codes[i]) == len(trajs[i]) for i in ids)

    if args.codes is not None:
        codes = read(args.codes)
        if not covers(codes):
            raise UserError(f"{args.codes} does not hold one code per step of each source episode; pass the "
                            "codes.npz that `digail segment` wrote for these demonstrations.")
        assert codes is not None
        return [codes[i] for i in ids]
    run = Path(str(args.vae))
    stored = read(run / "codes.npz") if (run / "codes.npz").is_file() else None
    if covers(stored):
        assert stored is not None
        return [stored[i] for i in ids]
    if not (run / "model.pt").is_file():
        raise UserError(f"{run} has no model.pt; pass the folder of a `digail pretrain` run as --vae.")
    from digail.algos.decode import segment_many
    from digail.checkpoint import load_model

    model, _ = load_model(run / "model.pt")
    return segment_many(model, [trajs[i] for i in ids])


def generate_command(args: GenerateArgs) -> dict[str, Any]:
    """Generate, write the dataset; returns the summary (attempts, successes, the rate, env steps)."""
    import dataclasses
    import shutil

    import numpy as np

    from digail.algos.frames import frames_from_text, infer_frames
    from digail.algos.generate import (
        GenerationPlan,
        chunk_segments,
        generate,
        generation_rate,
        plan_segments,
        runs_to_segments,
    )
    from digail.algos.trials import trial_frames, trial_sources
    from digail.commands.common import inputs
    from digail.data.minari_io import load_dataset
    from digail.data.minari_write import write_dataset
    from digail.data.robomimic import write_generated
    from digail.envs.registry import make_env, parse_env_args
    from digail.fsio import check_new_dir, check_not_locked, run_dir_lock

    if args.out.exists() or args.out.is_symlink():
        raise UserError(f"output {args.out} already exists and generate never replaces one; choose another --out.")
    check_new_dir(args.out, force=False, protected=inputs(args.demos, (args.vae, "the VAE run"),
                                                          (args.codes, "the codes file")))
    ds = load_dataset(args.demos)
    env_id = args.env or ds.env_id
    if env_id is None:
        raise UserError(f"{args.demos} does not record its environment; pass --env.")
    env_kwargs = parse_env_args(args.env_arg)
    scene = _scene(args, env_id)
    obs_dim = int(np.prod(ds.observation_space.shape or (0,)))
    act_dim = int(np.prod(ds.action_space.shape or (0,)))
    scene.check(obs_dim, act_dim)
    ids = _source_ids(args.sources, len(ds.trajs))
    trajs = [ds.trajs[i] for i in ids]
    if args.segments == "labels":
        if not all(t.subtasks is not None for t in trajs):
            raise UserError(f"{args.demos} has no sub-task labels; pass --segments codes with --vae RUN, or "
                            "--segments chunks or one.")
        segments = [runs_to_segments(np.asarray(t.subtasks)[:len(t)], args.min_segment) for t in trajs]
    elif args.segments == "codes":
        segments = [runs_to_segments(c, args.min_segment) for c in _codes(args, ds.trajs, ids)]
    elif args.segments == "chunks":
        segments = [chunk_segments(len(t), args.chunk) for t in trajs]
    else:
        segments = [chunk_segments(len(t), len(t)) for t in trajs]
    keys = sorted({s.key for segs in segments for s in segs})
    if args.frames is not None:
        frames = frames_from_text(args.frames, keys, scene)
    elif args.segments == "one":
        frames = {0: "object"}  # no sub-tasks: the whole path moves with the object, as MimicGen's single segment
    else:
        frames = infer_frames(trajs, segments, scene)
    order = None
    if args.order is not None:
        try:
            order = [int(x) for x in args.order.split(",") if x.strip()]
        except ValueError:
            raise UserError(f"--order {args.order!r} is not a list of sub-task ids; pass e.g. 3,2,1,0.") from None
        unknown = [k for k in order if k not in keys]
        if not order or unknown:
            raise UserError(f"--order names sub-task {unknown[0] if unknown else '(none)'}, which the segments do "
                            f"not have; name ids among {', '.join(map(str, keys))}.")
    planned = plan_segments(segments, order)
    usable = [i for i, p in enumerate(planned) if p]
    if not usable:
        raise UserError(f"no source demonstration has every sub-task of --order {args.order}; name sub-tasks every "
                        "source shows.")
    plan = GenerationPlan(env_id=env_id, sources=[trajs[i] for i in usable], source_ids=[ids[i] for i in usable],
                          segments=[planned[i] or [] for i in usable], frames=frames, scene=scene, gain=args.gain,
                          blend=args.blend, hold=args.hold, interp_speed=args.interp_speed, seed=args.seed,
                          pick="first" if args.pick == "best" else args.pick)
    work = args.out.with_name(args.out.name + ".partial")
    check_not_locked(work)
    trials: dict[str, Any] = {}
    trial_seed = args.seed + args.attempts
    if args.pick == "best":
        inferred = plan.frames
        plan, tried, trial_steps = trial_sources(plan, lambda: make_env(env_id, **env_kwargs), args.trial_scenes,
                                                 trial_seed, frame_trials=bool(args.frame_trials),
                                                 progress=args.progress)
        frames = plan.frames
        trials = {"source_trials": {"scenes": args.trial_scenes, "seed": trial_seed, "chosen": plan.source_ids[0],
                                    "inferred": {str(k): v for k, v in sorted(inferred.items())}, "tried": tried,
                                    "env_steps": trial_steps}}
        print(f"source by trial ({args.trial_scenes} scenes each, {trial_steps} env steps): "
              + ", ".join(f"{e['source']}: {e['successes']}" for e in tried) + f"; replaying {plan.source_ids[0]} "
              "in frames " + ", ".join(f"{k}: {v}" for k, v in sorted(frames.items())))
    elif args.frame_trials:
        inferred = plan.frames
        chosen, tried, trial_steps = trial_frames(plan, lambda: make_env(env_id, **env_kwargs), args.frame_trials,
                                                  trial_seed, progress=args.progress)
        plan = dataclasses.replace(plan, frames=chosen)
        frames = chosen
        trials = {"frame_trials": {"scenes": args.frame_trials, "seed": trial_seed,
                                   "inferred": {str(k): v for k, v in sorted(inferred.items())}, "tried": tried,
                                   "env_steps": trial_steps}}
        print(f"frames by trial ({args.frame_trials} scenes each, {trial_steps} env steps): "
              + ", ".join(f"{k}: {v}" for k, v in sorted(chosen.items())))
    name = env_id.rpartition("/")[2].lower().rsplit("-v", 1)[0]
    dataset_id = args.dataset_id or f"digail/{''.join(c for c in name if c.isalnum() or c in '-_')}/generated-v0"
    if work.exists():
        print(f"continuing the unfinished generation in {work}")
    work.mkdir(parents=True, exist_ok=True)
    with run_dir_lock(work):
        kept, state = generate(plan, lambda: make_env(env_id, **env_kwargs), args.attempts, args.successes, work,
                               progress=args.progress)
        rate = generation_rate(state)
        summary: dict[str, Any] = {
            "env_id": env_id, "demos": args.demos, "sources": plan.source_ids, "segments": args.segments,
            "frames": {str(k): v for k, v in sorted(frames.items())}, "order": order, "attempts": state.attempts,
            "successes": state.successes, "rate": rate, "env_steps": state.env_steps,
            "kept_steps": int(sum(len(t) for t in kept)), "gain": args.gain, "blend": args.blend,
            "hold": args.hold, "interp_speed": args.interp_speed, "seed": args.seed,
            "pick": args.pick, **({"env_kwargs": env_kwargs} if env_kwargs else {}), **trials}
        if not kept:
            raise UserError(f"none of the {state.attempts} attempts reached the env's success, so there is nothing "
                            f"to write (the attempts are recorded in {work}); try other --segments or --frames, or "
                            "more --attempts.")
        if args.format == "robomimic":
            write_generated(kept, args.out, env_id, state.episodes, summary)
        else:
            write_dataset(kept, args.out, env_id, dataset_id, seeds=[e["seed"] for e in state.episodes],
                          env_kwargs=env_kwargs,
                          algorithm_name="digail generate", description="demonstrations generated from the "
                          f"sub-tasks of {len(plan.sources)} source demonstration(s) of {args.demos}",
                          extra_metadata={"generation": {**summary, "episodes": state.episodes}})
    shutil.rmtree(work, ignore_errors=True)
    print(f"kept {state.successes} of {state.attempts} attempts (rate {rate:.3f}, {state.env_steps} env steps); "
          f"wrote {args.out}")
    return summary

