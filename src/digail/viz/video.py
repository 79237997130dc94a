"""Videos of a hierarchical policy: every frame shows the active code and the step.

Episodes run closed-loop (c_t = argmax q(. | s_t, c_{t-1}), exactly as `digail evaluate` does) or under a code
schedule (composition), one env at a time with `render_mode="rgb_array"`: the env's own image for Four Rooms and
Circle-World, offscreen MuJoCo for the MuJoCo envs. MuJoCo needs `MUJOCO_GL` before it is first imported:
`ensure_offscreen_gl` picks `egl`, falling back to `osmesa` where no EGL library is installed.

Each video is written twice: an MP4 (H.264 through imageio-ffmpeg) to download, and a smaller GIF (at most
`GIF_WIDTH` pixels wide, every `gif_stride`-th frame) that an HTML page can embed without JavaScript.
"""

from __future__ import annotations

import contextlib
import gc
import os
import sys
import traceback
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from digail.config import FINAL_EVAL_SEED
from digail.errors import UserError
from digail.utils import ensure_offscreen_gl, mujoco_gl_error, one_line

GIF_WIDTH = 320
"""Largest GIF width in pixels (frames are shrunk, never enlarged)."""
GIF_MAX_FRAMES = 150
"""Most frames a GIF keeps (the stride grows for long videos), so that a report embedding it stays small."""
BANNER_PIXELS = 24
"""Height of the caption strip drawn above every frame."""


@dataclass
class RenderedEpisode:
    """One episode: frames[t] is the image of the state in which codes[t] was chosen (plus the final one)."""

    frames: list[np.ndarray] = field(default_factory=list)
    codes: list[int] = field(default_factory=list)
    obs: list[np.ndarray] = field(default_factory=list)
    ret: float = 0.0
    final_info: dict[str, Any] = field(default_factory=dict)


def play_episodes(model: Any, env_id: str, episodes: int = 1, seed: int = 0, schedule: Sequence[int] | None = None,
                  render: bool = True, deterministic: bool = True,
                  max_steps: int | None = None, env_kwargs: dict[str, Any] | None = None) -> list[RenderedEpisode]:
    """Run `episodes` episodes (episode e reset with `seed + e`) and keep frames, codes and observations.

    Args:
        model: a `HierarchicalPolicy`.
        env_id: a registered environment id.
        schedule: code per step (the last repeats once it runs out); None for the closed-loop macro-policy.
        render: keep `env.render()` images (off for plots that need only states and codes).
        deterministic: pi's most likely / mean action, as in evaluation.
        max_steps: cut episodes after this many steps (software-rendered MuJoCo takes about half a second a
            frame on a loaded CPU); None plays them to their end.
        env_kwargs: keyword arguments for the env (`--env-arg`), e.g. the landmark route's order.
    """
    import gymnasium as gym

    from digail.algos.decode import hierarchical_act
    from digail.envs import make_env
    from digail.envs.actions import env_action_fn
    from digail.envs.episodes import Episode, play_batch
    from digail.envs.registry import env_spec

    spec = env_spec(env_id)
    if render and spec is not None and spec.render == "none":
        raise UserError(f"{env_id} cannot draw its frames (it has no rgb_array rendering); its runs have no video.")
    if render and (spec is None or spec.render == "mujoco"):
        ensure_offscreen_gl()
    kwargs = dict(env_kwargs or {})
    env = make_env(env_id, render_mode="rgb_array", **kwargs) if render else make_env(env_id, **kwargs)
    if max_steps is not None:
        env = gym.wrappers.TimeLimit(env, max_episode_steps=max_steps)  # the cut reads as a truncation
    policy = hierarchical_act(model, env_action_fn(env), deterministic=deterministic, schedule=schedule)
    frames: list[np.ndarray] = []  # of the episode being played
    out: list[RenderedEpisode] = []

    def act(envs: list[Any], obs: list[Any], eps: list[Episode]) -> Any:
        """The frame of the state the code and action are chosen in, then the policy's action."""
        if render:
            frames.append(_frame(env))
        return policy(envs, obs, eps)

    def done(ep: Episode) -> None:
        if render:
            frames.append(_frame(env))
        out.append(RenderedEpisode(frames=list(frames), codes=ep.codes, obs=[np.asarray(o) for o in ep.obs],
                                   ret=ep.ret, final_info=dict(ep.final_info)))
        frames.clear()

    try:
        play_batch([env], act, episodes, seed, keep=episodes, on_episode=done)
    except gym.error.DependencyNotInstalled as exc:  # e.g. Pendulum-v1 draws with pygame
        raise UserError(f"{env_id} cannot draw its frames here ({exc}); install that package to record a video."
                        ) from None
    finally:
        env.close()
    return out


def _frame(env: Any) -> np.ndarray:
    """`env.render()` as an array; a MuJoCo env that cannot draw under this `MUJOCO_GL` is one sentence."""
    try:
        return np.asarray(env.render())
    except (ImportError, RuntimeError, AttributeError, OSError) as exc:
        base = type(env.unwrapped)
        if "mujoco" not in f"{base.__module__}.{base.__name__}".lower():
            raise
        error = mujoco_gl_error(exc) or exc
        # the viewer Gymnasium half-built before the failure complains from its __del__ once collected: let go of
        # it here (the traceback's frames hold it), with that complaint silenced, so the sentence stays alone
        hook = sys.unraisablehook
        sys.unraisablehook = lambda _: None
        try:
            traceback.clear_frames(exc.__traceback__)
            del exc
            gc.collect()
        finally:
            sys.unraisablehook = hook
    raise error from None


def find_outcome(model: Any, env_id: str, success: bool, seed: int = FINAL_EVAL_SEED, search: int = 200,
                 max_steps: int | None = None) -> int:
    """The seed of the first episode from `seed` on whose last step's `info["is_success"]` is `success` (played
    without frames, so that only the chosen episode is rendered). Raises a UserError when the env reports no
    `is_success` or none of `search` episodes ends that way."""
    chunk = 10  # most policies show either outcome within a few episodes: do not play all `search` up front
    for start in range(0, search, chunk):
        eps = play_episodes(model, env_id, min(chunk, search - start), seed + start, render=False,
                            max_steps=max_steps)
        if start == 0 and not any("is_success" in e.final_info for e in eps):
            raise UserError(f"{env_id} reports no info['is_success'], so episodes cannot be chosen by outcome; "
                            "drop --outcome.")
        for i, ep in enumerate(eps):
            if bool(ep.final_info.get("is_success", False)) == success:
                return seed + start + i
    raise UserError(f"none of the {search} episodes from seed {seed} ended in "
                    f"{'success' if success else 'failure'}; try a larger --search or another --seed.")


def annotate(frame: np.ndarray, text: str, code: int | None) -> np.ndarray:
    """`frame` under a white caption strip holding `text`, with a swatch in the code's colour (tab10)."""
    from PIL import Image, ImageDraw, ImageFont

    from digail.viz.figures import code_colour

    img = np.asarray(frame, np.uint8)[..., :3]
    h, w = img.shape[:2]
    canvas = Image.new("RGB", (w, h + BANNER_PIXELS), (255, 255, 255))
    canvas.paste(Image.fromarray(img), (0, BANNER_PIXELS))
    draw = ImageDraw.Draw(canvas)
    try:
        font: Any = ImageFont.load_default(size=15)
    except TypeError:  # Pillow < 10.1 has one bitmap size
        font = ImageFont.load_default()
    x = 4
    if code is not None:
        rgb = tuple(int(255 * v) for v in code_colour(code)[:3])
        draw.rectangle((4, 4, 4 + BANNER_PIXELS - 8, BANNER_PIXELS - 4), fill=rgb)
        x += BANNER_PIXELS - 2
    draw.text((x, 3), text, fill=(0, 0, 0), font=font)
    return np.asarray(canvas)


def _pad16(frame: np.ndarray) -> np.ndarray:
    """Pad with white to multiples of 16 pixels, which H.264 encoders need (instead of imageio's resize)."""
    h, w = frame.shape[:2]
    ph, pw = -h % 16, -w % 16
    return np.pad(frame, ((0, ph), (0, pw), (0, 0)), constant_values=255) if ph or pw else frame


def captioned_frames(episodes: Sequence[RenderedEpisode], label: str = "") -> list[np.ndarray]:
    """Every frame of every episode with `ep e  step t  code c` (and `label`) drawn above it."""
    frames = []
    for e, ep in enumerate(episodes):
        for t, frame in enumerate(ep.frames):
            code = ep.codes[min(t, len(ep.codes) - 1)] if ep.codes else None
            text = f"ep {e}  step {t}  code {code}" + (f"  {label}" if label else "")
            frames.append(annotate(frame, text, code))
    return frames


def write_mp4_gif(frames: Sequence[np.ndarray], stem: Path, fps: int = 30, gif_stride: int = 2) -> tuple[Path, Path]:
    """Write `stem`.mp4 (every frame) and `stem`.gif (every `gif_stride`-th frame, at most GIF_WIDTH wide)."""
    import imageio.v2 as imageio
    from PIL import Image

    if not frames:
        raise ValueError("no frames to write")
    stem = Path(stem)
    created = not stem.parent.exists()
    stem.parent.mkdir(parents=True, exist_ok=True)
    mp4, gif = stem.with_suffix(".mp4"), stem.with_suffix(".gif")
    small: list[Any] = []
    gif_stride = max(gif_stride, -(-len(frames) // GIF_MAX_FRAMES))
    for f in frames[::max(1, gif_stride)]:
        img = Image.fromarray(f)
        if img.width > GIF_WIDTH:
            img = img.resize((GIF_WIDTH, round(img.height * GIF_WIDTH / img.width)), Image.Resampling.LANCZOS)
        small.append(np.asarray(img))
    # both go to temporary names first and are renamed once both are complete: no half-written video is left
    tmp_mp4, tmp_gif = (stem.with_name(f".{stem.name}.tmp-{os.getpid()}{ext}") for ext in (".mp4", ".gif"))
    try:
        try:
            imageio.mimsave(tmp_mp4, [_pad16(f) for f in frames], fps=fps, macro_block_size=1)
        except (BrokenPipeError, RuntimeError) as exc:  # ffmpeg stopped: its message says why
            raise UserError(f"ffmpeg could not write {mp4} ({one_line(exc).splitlines()[0][:200]}); check that "
                            "the folder is writable and has free space.") from None
        imageio.mimsave(tmp_gif, small, duration=1000 * max(1, gif_stride) / fps, loop=0)
        os.replace(tmp_mp4, mp4)
        os.replace(tmp_gif, gif)
    except BaseException:
        for tmp in (tmp_mp4, tmp_gif):
            tmp.unlink(missing_ok=True)
        if created:
            with contextlib.suppress(OSError):
                stem.parent.rmdir()  # the folder made for this video, now empty again
        raise
    return mp4, gif


def record_video(model: Any, env_id: str, path: Path, seed: int = 0, episodes: int = 1,
                 schedule: Sequence[int] | None = None, fps: int | None = None, label: str = "",
                 max_steps: int | None = None, env_kwargs: dict[str, Any] | None = None) -> tuple[Path, Path]:
    """Render `episodes` episodes (closed-loop, or under `schedule`) to `path` as MP4 and GIF.

    Args:
        path: the MP4 path or stem; the GIF goes beside it with the same name.
        fps: frames per second (default: the env's `render_fps`, else 30).
        label: extra caption text, e.g. the schedule.
        max_steps: cut each episode after this many steps (None: play it to its end).
        env_kwargs: keyword arguments for the env (`--env-arg`).

    Returns:
        The MP4 and GIF paths.
    """
    from digail.envs import make_env

    eps = play_episodes(model, env_id, episodes, seed, schedule=schedule, max_steps=max_steps,
                        env_kwargs=env_kwargs)
    if fps is None:
        probe = make_env(env_id)
        fps = int(probe.metadata.get("render_fps") or 30)
        probe.close()
    return write_mp4_gif(captioned_frames(eps, label), Path(path).with_suffix(""), fps=fps,
                         gif_stride=2 if fps >= 20 else 1)
