"""Fetch's shipped views of the state for D and the transport reward (`digail.envs.fetch`): what each keeps, the
distances view's indifference to how the layout is turned, and resuming a run that records one."""

from __future__ import annotations

import math
from pathlib import Path

import pytest
import torch

from digail.commands.train import check_recorded_view
from digail.envs.fetch import distances_view, log_distances_view, placing_view, relative_view
from digail.errors import UserError


def _turn(obs: torch.Tensor, angle: float) -> torch.Tensor:
    """The same scene turned about the vertical axis through the origin: every position and velocity's x, y."""
    c, s = math.cos(angle), math.sin(angle)
    rot = torch.tensor([[c, -s], [s, c]])
    out = obs.clone()
    for a in (0, 3, 6, 14, 20, 25):  # gripper, object, object - gripper, velocities, goal
        out[:, a:a + 2] = obs[:, a:a + 2] @ rot.T
    return out


def test_distances_view_is_the_same_for_a_turned_layout_and_the_others_are_not():
    gen = torch.Generator().manual_seed(0)
    obs = torch.randn(6, 28, generator=gen)
    obs[:, 6:9] = obs[:, 3:6] - obs[:, 0:3]
    turned = _turn(obs, 1.1)
    torch.testing.assert_close(distances_view(turned), distances_view(obs))
    torch.testing.assert_close(log_distances_view(turned), log_distances_view(obs))
    assert not torch.allclose(relative_view(turned), relative_view(obs))
    assert not torch.allclose(placing_view(turned), placing_view(obs))
    dist = distances_view(obs)
    assert dist.shape == (6, 8)
    torch.testing.assert_close(dist[:, 0], (obs[:, 3:6] - obs[:, 0:3]).norm(dim=-1))  # gripper to object
    torch.testing.assert_close(dist[:, 1], (obs[:, 25:27] - obs[:, 3:5]).norm(dim=-1))  # object to goal, across
    torch.testing.assert_close(dist[:, 2], obs[:, 27] - obs[:, 5])  # goal above the object
    logd = log_distances_view(obs)
    torch.testing.assert_close(logd[:, 0], (dist[:, 0] + 0.01).log())
    torch.testing.assert_close(logd[:, 1], ((obs[:, 25:28] - obs[:, 3:6]).norm(dim=-1) + 0.01).log())  # in 3-D
    torch.testing.assert_close(logd[:, 2:], dist[:, 2:])
    place = placing_view(obs)
    assert place.shape == (6, 10)
    torch.testing.assert_close(place[:, 3:6], obs[:, 25:28] - obs[:, 3:6])


def test_a_run_recording_a_shipped_view_resumes_without_naming_it():
    run = Path("runs/x")
    check_recorded_view(run, "digail.envs.fetch:distances_view", "all")
    check_recorded_view(run, "digail.envs.fetch:placing_view", "relative")
    check_recorded_view(run, "digail.envs.fetch:log_distances_view", "all")
    with pytest.raises(UserError, match="code that digail runs only when you name it"):
        check_recorded_view(run, "myviews:view", "all")
