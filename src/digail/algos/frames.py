"""Sub-task segments of source demonstrations and their reference frames (`digail generate`): the frames a scene has,
where their origins are in an observation, and each sub-task's frame inferred from the sources' end poses or named by
the user (the frames tried in the simulator are `digail.algos.generate.trial_frames`)."""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from digail.data.trajectory import Trajectory
from digail.envs.scene import SceneColumns
from digail.errors import UserError

Frame = str
"""a reference frame: `object`, `goal`, `world`, or `landmark<i>` in a scene with landmarks (`frame_names`)"""


@dataclass(frozen=True)
class Segment:
    """Steps `start` to `end` (actions, end exclusive) of a source demonstration, one sub-task `key`."""

    start: int
    """first action of the segment"""
    end: int
    """one past its last action"""
    key: int
    """what ties segments together across demonstrations (their label, code or chunk index); one frame per key"""


def frame_names(scene: SceneColumns) -> tuple[Frame, ...]:
    """The frames `scene` has: its object's and goal's where it observes them, its landmarks', and the world."""
    return (*(["object"] if scene.object is not None else []), *(["goal"] if scene.goal is not None else []),
            *(f"landmark{i}" for i in range(len(scene.landmarks))), "world")


def origin(obs: np.ndarray, frame: Frame, scene: SceneColumns) -> np.ndarray:
    """The position of `frame`'s origin in observation(s) `obs` (..., D)."""
    if frame == "world":
        return np.zeros(np.shape(obs)[:-1] + (scene.dim,))
    if frame not in frame_names(scene):
        raise UserError(f"a segment's frame is {frame!r}, which this env does not observe; name frames among "
                        f"{', '.join(frame_names(scene))}.")
    if frame == "object":
        cols = scene.object
    elif frame == "goal":
        cols = scene.goal
    else:
        cols = scene.landmarks[int(frame.removeprefix("landmark"))]
    return np.asarray(obs[..., cols], np.float64)


def infer_frames(trajs: Sequence[Trajectory], segments: Sequence[Sequence[Segment]], scene: SceneColumns
                 ) -> dict[int, Frame]:
    """Each segment key's reference frame.

    With two or more segments of a key (across demonstrations), the frame in which the end-effector's pose at the
    segments' ends is most consistent: the smallest mean squared distance to its mean, with the end pose taken
    relative to the object's position at the segment's start, to the goal's, a landmark's, or in the world. With
    one, the frame whose origin at the segment's start is nearest to the end-effector at the segment's end (not the
    world: its origin says nothing about the scene).
    """
    candidates = frame_names(scene)
    ends: dict[int, list[tuple[np.ndarray, np.ndarray]]] = {}
    for traj, segs in zip(trajs, segments, strict=True):
        for seg in segs:
            ends.setdefault(seg.key, []).append((traj.obs[seg.start], traj.obs[seg.end]))
    frames: dict[int, Frame] = {}
    for key, pairs in ends.items():
        if len(pairs) == 1:
            start, end = pairs[0]
            near = [f for f in candidates if f != "world"]
            # the origin where the segment starts, which is where the attempt anchors it: an object carried along
            # is always nearest to the hand at the segment's end, but was not where the carry ends
            dist = [np.linalg.norm(end[scene.ee] - origin(start, f, scene)) for f in near]
            frames[key] = near[int(np.argmin(dist))]
            continue
        spread = []
        for f in candidates:
            rel = np.stack([end[scene.ee] - origin(start, f, scene) for start, end in pairs])
            spread.append(float(((rel - rel.mean(0)) ** 2).sum(-1).mean()))
        frames[key] = candidates[int(np.argmin(spread))]
    return frames


def frames_from_text(text: str, keys: Sequence[int], scene: SceneColumns) -> dict[int, Frame]:
    """'object,goal,...' (one frame per key, in key order) -> {key: frame}, refused in one sentence otherwise."""
    names = [n.strip() for n in text.split(",") if n.strip()]
    known = frame_names(scene)
    bad = [n for n in names if n not in known]
    if bad:
        raise UserError(f"--frames names {bad[0]!r}, which is no frame of this env; name one of {', '.join(known)} "
                        "for each sub-task, e.g. object,object,goal,goal.")
    keys = sorted(keys)
    if len(names) != len(keys):
        raise UserError(f"--frames names {len(names)} frames but the segments have {len(keys)} sub-tasks "
                        f"({', '.join(map(str, keys))}); name one frame per sub-task.")
    return dict(zip(keys, names, strict=True))
