"""Data generation from sub-tasks (MimicGen's recipe, Mandlekar et al., CoRL 2023, on sub-tasks found or labelled).

Each source demonstration is cut into segments (`Segment`: its sub-tasks, from oracle labels, a pre-trained run's
codes, fixed-length chunks or the whole demonstration). Each segment key (a label, a code, a chunk index) is tied to
a reference frame, `object`, `goal` or `world` (`digail.algos.frames.infer_frames`): the one in which the segment's
end pose of the end-effector is most consistent across the demonstrations, or the nearest to it at its end when
there is one demonstration; or the one whose attempts succeed most often (`digail.algos.trials`). The frames are
translations: the scenes of Fetch and Meta-World place their objects and goals at random positions, not
orientations.

An attempt (`attempt`) resets the env to a new scene, then for each source segment in turn moves the segment's
end-effector path into its frame's position in the new scene (the object's position when the segment starts, the
goal's, or unchanged) and tracks it with the env's move actions, a proportional controller clipped to the action
bounds, keeping the source's gripper actions. The offset between where the end-effector is when a segment starts and
where the moved path starts decays linearly over the segment's first `blend` steps, so consecutive segments join
smoothly without extra steps. Attempts that reach the env's success are kept (`generate`).
"""

from __future__ import annotations

import json
import math
from collections.abc import Callable, Sequence
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any, Literal

import numpy as np

from digail.algos.frames import Frame, Segment, frame_names, origin
from digail.data.trajectory import SUBTASK_KEY, Trajectory
from digail.envs.metaworld import merge_short_runs
from digail.envs.scene import SceneColumns
from digail.errors import UserError


def runs_to_segments(labels: np.ndarray, min_len: int = 1) -> list[Segment]:
    """Per-step labels (T,) as segments, one per run of equal labels, runs shorter than `min_len` merged into a
    neighbour first (`merge_short_runs`: a one-step flicker is not a sub-task)."""
    labels = np.asarray(labels, np.int64)
    if min_len > 1:
        labels = merge_short_runs(labels, min_len)
    change = np.flatnonzero(np.diff(labels)) + 1
    starts = np.concatenate([[0], change])
    ends = np.concatenate([change, [len(labels)]])
    return [Segment(int(s), int(e), int(labels[s])) for s, e in zip(starts, ends, strict=True)]


def chunk_segments(length: int, chunk: int) -> list[Segment]:
    """Fixed-length segments of `chunk` steps (the last may be shorter), keyed by their index."""
    return [Segment(s, min(s + chunk, length), i) for i, s in enumerate(range(0, length, chunk))]


@dataclass
class AttemptResult:
    """One attempt: the episode it played and whether it reached the env's success."""

    traj: Trajectory
    """what the env observed and was given"""
    success: bool
    """the env's success at the episode's end"""
    steps: int
    """env steps taken"""
    segments: list[dict[str, Any]] = field(default_factory=list)
    """per source segment: its steps in the source, its key and frame, and the step where it began here"""


def _success(info: dict[str, Any]) -> bool:
    return bool(info.get("is_success", info.get("success", False)))


def attempt(env: Any, source: Trajectory, segments: Sequence[Segment], frames: dict[int, Frame],
            scene: SceneColumns, seed: int, *, gain: float = 1.0, blend: int = 5, hold: int = 0,
            interp_speed: float = 0.0) -> AttemptResult:
    """Play one attempt in `env` reset with `seed` (module doc): the source's segments, in the given order, each in
    its frame's position in the new scene.

    Args:
        env: the env (a Gymnasium env with the time limit of its registration).
        source: the source demonstration.
        segments: its segments, in the order to play them.
        frames: the reference frame of each segment key.
        scene: the env's columns.
        seed: the reset seed (the new scene).
        gain: the share of the position error the move actions correct in one step (1: all of it, as far as the
            action bounds allow).
        blend: steps over which a segment's start offset decays to zero.
        hold: steps the last target and gripper action are held after the path while the env has not succeeded.
        interp_speed: 0, or action units per step of a straight move inserted before a segment whose moved path
            starts further away than one such step (MimicGen's interpolation, which costs steps but never asks the
            end-effector to go faster than the source did).
    """
    obs, info = env.reset(seed=int(seed))
    obs = np.asarray(obs, np.float64)
    obs_list, acts, rews, labels = [obs], [], [], [info.get(SUBTASK_KEY)]
    src_obs = np.asarray(source.obs, np.float64)
    src_acts = np.asarray(source.acts, np.float32)
    if scene.integrating:
        # the target the source's actions accumulated, from where its end-effector started
        moves = np.clip(src_acts[:, scene.move_actions], -1.0, 1.0) * scene.action_scale
        src_pos = src_obs[0, scene.ee] + np.concatenate([np.zeros((1, scene.dim)), np.cumsum(moves, 0)])
    else:
        src_pos = src_obs[:, scene.ee]
    command = obs[scene.ee].copy()  # the integrating target, dead-reckoned
    done, last_info, steps = False, info, 0
    record: list[dict[str, Any]] = []
    final: np.ndarray | None = None  # the path's last target, held after it

    def here() -> np.ndarray:
        return command if scene.integrating else obs[scene.ee]

    def step(target: np.ndarray, template: np.ndarray) -> None:
        nonlocal obs, done, last_info, steps, command
        act = template.copy()
        move = np.clip(gain * (target - here()) / scene.action_scale, -1.0, 1.0)
        act[scene.move_actions] = move
        command = command + move * scene.action_scale
        obs_next, rew, terminated, truncated, info = env.step(act)
        obs = np.asarray(obs_next, np.float64)
        obs_list.append(obs)
        acts.append(act)
        rews.append(float(rew))
        labels.append(info.get(SUBTASK_KEY))
        last_info, steps = info, steps + 1
        done = bool(terminated or truncated)
        if terminated:
            last_info = {**info, "_terminated": True}

    for seg in segments:
        if done:
            break
        frame = frames[seg.key]
        # the path after each of the segment's actions, moved from the source scene's frame to this one's
        shift = origin(obs, frame, scene) - origin(src_obs[seg.start], frame, scene)
        start = src_pos[seg.start] + shift
        record.append({"start": seg.start, "end": seg.end, "key": seg.key, "frame": frame, "at": steps})
        gap = float(np.linalg.norm(start - here()))
        if interp_speed > 0 and gap > interp_speed * scene.action_scale:
            template = acts[-1] if acts else src_acts[seg.start]
            n, here_0 = math.ceil(gap / (interp_speed * scene.action_scale)), here().copy()
            for i in range(n):
                if done:
                    break
                step(here_0 + (start - here_0) * (i + 1) / n, template)
        path = src_pos[seg.start + 1:seg.end + 1] + shift
        offset = here() - start
        n = len(path)
        ramp = max(1, min(blend, n))
        for i in range(n):
            if done:
                break
            w = max(0.0, 1.0 - (i + 1) / ramp)
            step(path[i] + w * offset, src_acts[seg.start + i])
        final = path[-1]
    if final is not None:
        for _ in range(hold):
            if done or _success(last_info):
                break
            step(final, src_acts[segments[-1].end - 1])
    traj = Trajectory(
        obs=np.asarray(obs_list, np.float32), acts=np.asarray(acts, np.float32),
        rews=np.asarray(rews, np.float32),
        subtasks=np.asarray(labels, np.int64) if all(lb is not None for lb in labels) else None,
        terminated=bool(last_info.get("_terminated", False)))
    return AttemptResult(traj, _success(last_info), steps, record)


def plan_segments(sources: Sequence[Sequence[Segment]], order: Sequence[int] | None
                  ) -> list[list[Segment] | None]:
    """Each source's segments in the order to play them: as demonstrated, or, with `order`, for each key of the
    order the source's first segment with that key (None for a source lacking one of the keys)."""
    if order is None:
        return [list(s) for s in sources]
    out: list[list[Segment] | None] = []
    for segs in sources:
        first: dict[int, Segment] = {}
        for seg in segs:
            first.setdefault(seg.key, seg)
        out.append([first[k] for k in order] if all(k in first for k in order) else None)
    return out


@dataclass(frozen=True)
class GenerationPlan:
    """What `generate` plays: the sources, their segments (in playing order), the frames and the controller."""

    env_id: str
    """the env the attempts run in"""
    sources: list[Trajectory]
    """the source demonstrations"""
    source_ids: list[int]
    """each source's episode index in its dataset"""
    segments: list[list[Segment]]
    """each source's segments, in the order an attempt plays them"""
    frames: dict[int, Frame]
    """each segment key's reference frame"""
    scene: SceneColumns
    """the env's columns"""
    gain: float = 1.0
    """share of the position error corrected per step"""
    blend: int = 5
    """steps over which a segment's start offset decays"""
    hold: int = 10
    """steps the path's end is held after it, until success"""
    interp_speed: float = 1.0
    """0, or action units per step of the straight moves inserted before segments that start far away"""
    seed: int = 0
    """attempt i is reset with seed + i"""
    pick: Literal["cycle", "nearest", "first"] = "cycle"
    """which source an attempt replays: source i mod len(sources) (`cycle`), the one whose scene is nearest to
    the new one (`nearest`: `nearest_source`), or always the first (`first`: the others only inform the frames)"""

    def fingerprint(self) -> dict[str, Any]:
        """What makes two plans play the same attempts (what a resumed run must match)."""
        return {"env_id": self.env_id, "source_ids": self.source_ids,
                "segments": [[asdict(s) for s in segs] for segs in self.segments],
                "frames": {str(k): v for k, v in sorted(self.frames.items())},
                "gain": self.gain, "blend": self.blend, "hold": self.hold, "seed": self.seed,
                "interp_speed": self.interp_speed, "integrating": self.scene.integrating,
                **({"pick": self.pick} if self.pick != "cycle" else {}),
                "source_steps": [len(t) for t in self.sources]}


@dataclass
class GenerationState:
    """Progress of a generation: attempts played, successes kept and the env steps spent."""

    attempts: int = 0
    successes: int = 0
    env_steps: int = 0
    episodes: list[dict[str, Any]] = field(default_factory=list)
    """per kept episode: the attempt, its seed, the source, the segments with their frames"""


CHECKPOINT_EVERY = 25
"""attempts between two saves of a resumable generation"""


def _save_chunk(folder: Path, index: int, trajs: list[Trajectory]) -> None:
    import io

    from digail.fsio import atomic_write_bytes

    arrays: dict[str, np.ndarray] = {}
    for i, t in enumerate(trajs):
        arrays[f"obs_{i:05d}"] = t.obs
        arrays[f"acts_{i:05d}"] = t.acts
        arrays[f"rews_{i:05d}"] = np.asarray(t.rews, np.float32)
        arrays[f"term_{i:05d}"] = np.asarray(t.terminated)
        if t.subtasks is not None:
            arrays[f"subtasks_{i:05d}"] = t.subtasks
    buf = io.BytesIO()
    np.savez(buf, **arrays)  # type: ignore[arg-type]
    atomic_write_bytes(folder / f"chunk_{index:05d}.npz", buf.getvalue())


def _load_chunks(folder: Path, count: int) -> list[Trajectory]:
    trajs: list[Trajectory] = []
    for index in range(count):
        with np.load(folder / f"chunk_{index:05d}.npz", allow_pickle=False) as z:
            n = sum(1 for k in z.files if k.startswith("obs_"))
            for i in range(n):
                sub = f"subtasks_{i:05d}"
                trajs.append(Trajectory(obs=z[f"obs_{i:05d}"], acts=z[f"acts_{i:05d}"], rews=z[f"rews_{i:05d}"],
                                        subtasks=z[sub] if sub in z.files else None,
                                        terminated=bool(z[f"term_{i:05d}"])))
    return trajs


def scene_positions(obs: np.ndarray, scene: SceneColumns) -> np.ndarray:
    """The scene's layout in an observation: the positions of its object, goal and landmarks (those it has)."""
    return np.concatenate([origin(obs, f, scene) for f in frame_names(scene) if f != "world"])


def nearest_source(obs: np.ndarray, sources: Sequence[Trajectory], scene: SceneColumns) -> int:
    """The source whose first observation places the object (and goal) nearest to `obs`'s.

    Replaying the nearest source makes the generated action a function of the scene: with sources taken in turn,
    one scene can come with any source's way of doing the task, and a behaviour-cloned policy averages them.
    """
    here = scene_positions(obs, scene)
    dist = [float(np.linalg.norm(scene_positions(np.asarray(t.obs[0]), scene) - here)) for t in sources]
    return int(np.argmin(dist))


def generate(plan: GenerationPlan, make_env: Callable[[], Any], attempts: int, successes: int | None,
             work: Path, *, progress: bool = True) -> tuple[list[Trajectory], GenerationState]:
    """Play attempts until `attempts` were played or `successes` kept, saving progress into `work` every
    `CHECKPOINT_EVERY` attempts, so that a run stopped part-way continues where it was saved (the attempts are
    seeded: the result is the same as an uninterrupted run's). A `work` folder of another plan is refused.

    Returns:
        The kept episodes and the state (attempts, successes, env steps, each episode's record).
    """
    from digail.fsio import write_json
    from digail.utils import progress_bar

    work.mkdir(parents=True, exist_ok=True)
    state_file = work / "state.json"
    fingerprint = json.loads(json.dumps(plan.fingerprint()))
    state, chunks = GenerationState(), 0
    if state_file.exists():
        saved = json.loads(state_file.read_text())
        if saved.get("plan") != fingerprint:
            raise UserError(f"{work} holds an unfinished generation with other settings; pass the settings it was "
                            "started with to continue it, or remove that folder to start again.")
        state = GenerationState(saved["attempts"], saved["successes"], saved["env_steps"], saved["episodes"])
        chunks = saved["chunks"]
    else:
        write_json(state_file, {"plan": fingerprint, "attempts": 0, "successes": 0, "env_steps": 0,
                                "episodes": [], "chunks": 0})
    kept = _load_chunks(work, chunks)
    pending: list[Trajectory] = []
    env = make_env()
    bar = progress_bar(attempts, progress, desc="generate", unit="attempt", initial=state.attempts)
    bar.set_postfix(successes=state.successes, refresh=False)
    try:
        while state.attempts < attempts and (successes is None or state.successes < successes):
            i = state.attempts
            src = source_for(plan, env, i, plan.seed + i)
            result = replay(plan, env, src, plan.frames, plan.seed + i)
            state.attempts += 1
            state.env_steps += result.steps
            if result.success:
                state.successes += 1
                pending.append(result.traj)
                state.episodes.append({"attempt": i, "seed": plan.seed + i, "source": plan.source_ids[src],
                                       "env_steps": state.env_steps, "segments": result.segments})
            bar.update(1)
            bar.set_postfix(successes=state.successes, rate=f"{state.successes / state.attempts:.2f}",
                            refresh=False)
            if state.attempts % CHECKPOINT_EVERY == 0:
                chunks, pending = _save(work, state_file, fingerprint, state, chunks, pending, kept)
        # the end is saved too: a generation that kept nothing still says what it tried
        chunks, pending = _save(work, state_file, fingerprint, state, chunks, pending, kept)
    finally:
        bar.close()
        env.close()
    return kept, state


def source_for(plan: GenerationPlan, env: Any, i: int, seed: int) -> int:
    """The source attempt `i` (reset with `seed`) replays under the plan's `pick`."""
    if plan.pick == "first":
        return 0
    if plan.pick == "nearest" and len(plan.sources) > 1:
        first, _ = env.reset(seed=seed)  # `attempt` resets with the same seed: the same scene
        return nearest_source(np.asarray(first), plan.sources, plan.scene)
    return i % len(plan.sources)


def replay(plan: GenerationPlan, env: Any, src: int, frames: dict[int, Frame], seed: int) -> AttemptResult:
    """One attempt of `plan` replaying source `src` in `frames`, on the scene reset with `seed`."""
    return attempt(env, plan.sources[src], plan.segments[src], frames, plan.scene, seed, gain=plan.gain,
                   blend=plan.blend, hold=plan.hold, interp_speed=plan.interp_speed)


def _save(work: Path, state_file: Path, fingerprint: dict[str, Any], state: GenerationState, chunks: int,
          pending: list[Trajectory], kept: list[Trajectory]) -> tuple[int, list[Trajectory]]:
    """Write the pending episodes as the next chunk, then the state naming it; the pending join `kept`."""
    from digail.fsio import write_json

    if pending:
        _save_chunk(work, chunks, pending)
        chunks += 1
        kept += pending
    write_json(state_file, {"plan": fingerprint, **asdict(state), "chunks": chunks})
    return chunks, []


def generation_rate(state: GenerationState) -> float:
    """Successes per attempt (0 before any attempt)."""
    return state.successes / state.attempts if state.attempts else 0.0
