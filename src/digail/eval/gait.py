"""How consistent the codes of a locomotion run are with the motion: a gait-phase label and its agreement with codes.

There are no oracle sub-task labels on Hopper or Walker2d, so the paper's claim that codes follow the gait is
checked against a phase computed from the observation alone. The phase of a periodic joint is the angle in its
phase portrait: with the hip (thigh) angle theta and its velocity omega, each standardised by the demonstrations'
mean and standard deviation, phi = atan2(-omega', theta') walks once around the circle per stride. It is cut into
`bins` equal sectors, so a label says "hip forward and swinging back", "hip back and swinging forward", and so on.
Foot contacts would need simulator data that the observation does not carry; the hip phase needs only what the
policy sees, so it can be computed for demonstrations and rollouts alike.

Scores (`code_phase_scores`): the mutual information between the code and the phase label in bits, its normalised
form (NMI, 0 for independent, 1 for a relabelling), and how often codes switch per 100 steps.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
from sklearn.metrics import mutual_info_score, normalized_mutual_info_score


def hip_features(env_id: str) -> tuple[int, int]:
    """The (angle, velocity) observation indices of the hip joint whose phase labels the gait
    (`digail.envs.registry.EnvSpec.gait_features`)."""
    from digail.envs.registry import ENV_SPECS

    spec = ENV_SPECS.get(env_id)
    if spec is None or spec.gait_features is None:
        known = ", ".join(s.env_id for s in ENV_SPECS.values() if s.gait_features is not None)
        raise ValueError(f"no gait phase is defined for {env_id}; known: {known}.")
    return spec.gait_features


def phase_stats(obs: Sequence[np.ndarray], env_id: str) -> np.ndarray:
    """Mean and standard deviation of the hip angle and velocity over `obs`: [[mu_a, mu_v], [sd_a, sd_v]]."""
    a, v = hip_features(env_id)
    x = np.concatenate([np.asarray(o, np.float64).reshape(len(o), -1)[:, [a, v]] for o in obs])
    return np.stack([x.mean(0), x.std(0) + 1e-8])


def gait_phase(obs: np.ndarray, env_id: str, stats: np.ndarray, bins: int = 4) -> np.ndarray:
    """The phase-sector label (T,) in [0, bins) of each observation (T, obs_dim), standardised with `stats`."""
    a, v = hip_features(env_id)
    x = (np.asarray(obs, np.float64).reshape(len(obs), -1)[:, [a, v]] - stats[0]) / stats[1]
    phi = np.arctan2(-x[:, 1], x[:, 0])  # in (-pi, pi]
    return np.minimum(((phi + np.pi) / (2 * np.pi) * bins).astype(np.int64), bins - 1)


def code_phase_scores(codes: Sequence[np.ndarray], phases: Sequence[np.ndarray]) -> dict[str, float]:
    """Agreement of codes with phase labels over all steps, and switches per 100 steps."""
    c = np.concatenate([np.asarray(x, np.int64) for x in codes])
    p = np.concatenate([np.asarray(x, np.int64) for x in phases])
    if len(c) != len(p):
        raise ValueError(f"{len(c)} codes but {len(p)} phase labels; give one label per coded step.")
    switches = sum(int((np.diff(np.asarray(x)) != 0).sum()) for x in codes)
    return {
        "mi_bits": float(mutual_info_score(p, c) / np.log(2)),
        "nmi": float(normalized_mutual_info_score(p, c)),
        "phase_entropy_bits": float(_entropy_bits(p)),
        "codes_used": int(len(np.unique(c))),
        "switches_per_100_steps": float(100.0 * switches / max(len(c), 1)),
        "steps": int(len(c)),
    }


def _entropy_bits(x: np.ndarray) -> float:
    p = np.bincount(x) / len(x)
    p = p[p > 0]
    return float(-(p * np.log2(p)).sum())
