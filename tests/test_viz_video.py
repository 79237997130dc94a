"""Videos: frames, codes and observations line up; the schedule and the step cut are obeyed; MP4 and GIF are
written with the caption strip on every frame; Pendulum draws with the declared dependencies; the GL backend falls
back to OSMesa without EGL."""

from __future__ import annotations

import ctypes.util
import os

import imageio.v2 as imageio
import numpy as np
import pytest
import torch

from digail.cli import main
from digail.nets.policy import ActionSpec
from digail.nets.vae import HierarchicalPolicy
from digail.utils import ensure_offscreen_gl
from digail.viz.video import BANNER_PIXELS, annotate, play_episodes, record_video


def _circle_model() -> HierarchicalPolicy:
    torch.manual_seed(0)
    return HierarchicalPolicy(2, 2, ActionSpec(False, 2))


def test_play_episodes_schedule_and_cut():
    eps = play_episodes(_circle_model(), "digail/CircleWorld-v0", 2, 0, schedule=[1] * 4 + [0], max_steps=9)
    for ep in eps:
        assert ep.codes == [1, 1, 1, 1, 0, 0, 0, 0, 0]
        assert len(ep.obs) == len(ep.frames) == 10  # the state before every step and the final one
        assert ep.frames[0].shape == (256, 256, 3)
    full = play_episodes(_circle_model(), "digail/CircleWorld-v0", 1, 0, render=False)[0]
    assert len(full.codes) == 120 and len(full.obs) == 121 and not full.frames


def test_record_video_writes_captioned_mp4_and_gif(tmp_path):
    mp4, gif = record_video(_circle_model(), "digail/CircleWorld-v0",
                            tmp_path / "v.mp4", episodes=1, max_steps=12, label="test")
    assert mp4.stat().st_size > 1000 and gif.stat().st_size > 1000
    frames = imageio.mimread(gif)
    assert len(frames) >= 6 and frames[0].shape[0] == 256 + BANNER_PIXELS
    first = annotate(np.zeros((20, 40, 3), np.uint8), "step 0  code 1", 1)
    assert first.shape == (20 + BANNER_PIXELS, 40, 3) and first[:BANNER_PIXELS].min() < 255


def test_pendulum_video_draws_with_the_declared_dependencies(tmp_path):
    """Pendulum-v1 draws its frames with pygame (gymnasium's classic-control extra, a dependency of digail)."""
    torch.manual_seed(0)
    model = HierarchicalPolicy(3, 2, ActionSpec(False, 1))
    mp4, gif = record_video(model, "Pendulum-v1", tmp_path / "pendulum.mp4", episodes=1, max_steps=6)
    frames = imageio.mimread(gif)
    assert mp4.stat().st_size > 1000 and frames[0].shape[0] > BANNER_PIXELS
    body = np.asarray(frames[0])[BANNER_PIXELS:]
    assert body.std() > 5, "the pendulum frame is blank"


@pytest.mark.parametrize(("libs", "want"), [({"EGL", "OSMesa"}, "egl"), ({"OSMesa"}, "osmesa"), (set(), "egl")])
def test_offscreen_gl_falls_back_to_osmesa_without_egl(monkeypatch, tmp_path, libs, want):
    """The CLI picks MUJOCO_GL before MuJoCo loads: EGL where its library is installed, else OSMesa; a value the
    user set is kept."""
    monkeypatch.setattr(ctypes.util, "find_library", lambda name: f"lib{name}.so" if name in libs else None)
    monkeypatch.delenv("MUJOCO_GL", raising=False)
    assert main(["report", str(tmp_path / "missing")]) == 2  # any command: the choice comes first
    assert os.environ["MUJOCO_GL"] == want
    monkeypatch.setenv("MUJOCO_GL", "glfw")
    assert ensure_offscreen_gl() == "glfw"


def _four_rooms_model() -> HierarchicalPolicy:
    from digail.envs import make_env

    env = make_env("digail/FourRooms-v0")
    torch.manual_seed(0)
    return HierarchicalPolicy(env.observation_space.shape[0], 4, ActionSpec(True, 4))


def test_find_outcome_picks_the_first_episode_that_ends_that_way(monkeypatch):
    from digail.errors import UserError
    from digail.viz import video

    ends = [False, False, True, False, True]
    fake = [video.RenderedEpisode(final_info={"is_success": e}) for e in ends]
    monkeypatch.setattr(video, "play_episodes", lambda model, env_id, n, seed, **kw: fake[:n])
    assert video.find_outcome(None, "x", True, seed=100, search=5) == 102
    assert video.find_outcome(None, "x", False, seed=100, search=5) == 100
    with pytest.raises(UserError, match="none of the 2 episodes from seed 100 ended in success"):
        video.find_outcome(None, "x", True, seed=100, search=2)


def test_video_outcome_on_real_episodes(tmp_path):
    """An untrained Four Rooms policy never reaches the apple: its first failure is the first episode, a success
    is reported missing; Circle-World has no is_success to choose by."""
    from digail.errors import UserError
    from digail.viz.video import find_outcome

    model = _four_rooms_model()
    seed = find_outcome(model, "digail/FourRooms-v0", False, seed=7, search=3)
    assert seed == 7
    assert not play_episodes(model, "digail/FourRooms-v0", 1, seed, render=False)[0].final_info["is_success"]
    with pytest.raises(UserError, match="ended in success"):
        find_outcome(model, "digail/FourRooms-v0", True, seed=7, search=3)
    with pytest.raises(UserError, match="reports no info"):
        find_outcome(_circle_model(), "digail/CircleWorld-v0", True, search=2)


def test_video_env_is_made_with_the_env_arguments(monkeypatch: pytest.MonkeyPatch, tmp_path) -> None:
    """`digail evaluate --video --env-arg ...` records in the env the evaluation ran in, not the default one."""
    import digail.envs

    made: list[dict] = []
    real = digail.envs.make_env

    def spy(env_id: str, **kwargs: object) -> object:
        made.append(kwargs)
        return real(env_id, **{k: v for k, v in kwargs.items() if k != "probe"})

    monkeypatch.setattr(digail.envs, "make_env", spy)
    record_video(_circle_model(), "digail/CircleWorld-v0", tmp_path / "v.mp4", max_steps=3, env_kwargs={"probe": 1})
    assert made[0] == {"render_mode": "rgb_array", "probe": 1}
