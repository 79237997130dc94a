"""The expert's reference return is measured once per (env, episodes, seed) and read from the cache afterwards."""

from __future__ import annotations

import json

import pytest

import digail.eval.returns as returns
from digail.eval.returns import expert_cache_file, expert_summary


def test_expert_reference_is_measured_once_then_cached(tmp_path, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv("DIGAIL_CACHE_DIR", str(tmp_path))
    first = expert_summary("digail/FourRooms-v0", 3, 7)
    assert first is not None and first["episodes"] == 3 and first["success_rate"] == 1.0
    cached = json.loads(expert_cache_file().read_text())
    assert len(cached) == 1 and "digail/FourRooms-v0|episodes=3|seed=7" in next(iter(cached))

    def no_playing(*args, **kwargs):
        raise AssertionError("the expert was played again")

    monkeypatch.setattr(returns, "play_episodes", no_playing)
    assert expert_summary("digail/FourRooms-v0", 3, 7) == first
    with pytest.raises(AssertionError, match="played again"):  # another seed is a new measurement
        expert_summary("digail/FourRooms-v0", 3, 8)


def test_env_without_expert_has_no_reference(tmp_path, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv("DIGAIL_CACHE_DIR", str(tmp_path))
    assert expert_summary("CartPole-v1", 2, 0) is None
