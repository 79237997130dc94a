"""The gait-phase label and its agreement score with codes (digail.eval.gait)."""

import numpy as np
import pytest

from digail.eval.gait import code_phase_scores, gait_phase, phase_stats


def _stride_obs(steps: int = 400, period: int = 40) -> np.ndarray:
    """Hopper-shaped observations whose hip swings sinusoidally: angle sin, velocity its derivative."""
    t = np.arange(steps) * 2 * np.pi / period
    obs = np.zeros((steps, 11))
    obs[:, 2], obs[:, 8] = 0.3 * np.sin(t), 0.3 * np.cos(t)
    return obs


def test_phase_walks_once_around_per_stride() -> None:
    obs = _stride_obs()
    labels = gait_phase(obs, "Hopper-v5", phase_stats([obs], "Hopper-v5"))
    assert set(labels.tolist()) == {0, 1, 2, 3}
    # one stride of 40 steps visits each sector for about a quarter of it, in a fixed cyclic order
    assert np.bincount(labels).min() >= 90
    changes = np.flatnonzero(np.diff(labels))
    assert len(changes) == 4 * 10 - 1 or len(changes) == 4 * 10
    assert set(((labels[changes + 1] - labels[changes]) % 4).tolist()) == {1}


def test_codes_that_follow_the_phase_score_one_and_random_codes_zero() -> None:
    obs = _stride_obs()
    labels = gait_phase(obs, "Hopper-v5", phase_stats([obs], "Hopper-v5"))
    same = code_phase_scores([(labels + 2) % 4], [labels])
    assert same["nmi"] == pytest.approx(1.0)
    assert same["mi_bits"] == pytest.approx(2.0, abs=0.01)
    noise = code_phase_scores([np.random.default_rng(0).integers(0, 4, len(labels))], [labels])
    assert noise["nmi"] < 0.05
    constant = code_phase_scores([np.zeros(len(labels), np.int64)], [labels])
    assert constant["mi_bits"] == 0.0 and constant["switches_per_100_steps"] == 0.0


def test_unknown_env_is_refused() -> None:
    with pytest.raises(ValueError, match="no gait phase"):
        phase_stats([np.zeros((3, 3))], "Pendulum-v1")
