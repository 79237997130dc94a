"""Figures: rolled-out paths coloured by code, codes over time, training curves."""

from __future__ import annotations

import csv
from pathlib import Path
from typing import Any

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

CODE_COLORS = plt.get_cmap("tab10")


def plot_episodes(episodes: list[Any], path: Path, title: str = "", max_episodes: int = 6) -> Path:
    """Paths in the plane coloured by code (2-D observations), else the code sequence of each episode."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    shown = [e for e in episodes if e.obs][:max_episodes] or episodes[:max_episodes]
    two_d = bool(shown and shown[0].obs and np.asarray(shown[0].obs[0]).shape == (2,))
    fig, ax = plt.subplots(figsize=(5, 5) if two_d else (8, 0.5 + 0.4 * len(shown)))
    if two_d:
        for e in shown:
            xy = np.asarray(e.obs)
            for t, c in enumerate(e.codes):
                ax.plot(xy[t : t + 2, 0], xy[t : t + 2, 1], color=CODE_COLORS(c % 10), lw=1.5)
            ax.plot(xy[0, 0], xy[0, 1], "k*", ms=8)
        ax.set_aspect("equal")
        ax.set_xlabel("x")
        ax.set_ylabel("y")
    else:
        for row, e in enumerate(shown):
            ax.scatter(np.arange(len(e.codes)), np.full(len(e.codes), row), c=[CODE_COLORS(c % 10) for c in e.codes],
                       marker="s", s=12)
        ax.set_xlabel("step")
        ax.set_ylabel("episode")
    codes = sorted({c for e in shown for c in e.codes})
    for c in codes:
        ax.plot([], [], color=CODE_COLORS(c % 10), label=f"code {c}")
    if codes:
        ax.legend(loc="best", fontsize=8)
    ax.set_title(title)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path


def plot_training(run_dir: Path, path: Path | None = None) -> Path | None:
    """Training curves from RUN/metrics.csv: episode return, discriminator accuracy, bonus, steps/s."""
    metrics = Path(run_dir) / "metrics.csv"
    if not metrics.exists():
        return None
    with open(metrics) as f:
        rows = list(csv.DictReader(f))
    if not rows:
        return None
    path = Path(path) if path is not None else Path(run_dir) / "figures" / "training.png"
    path.parent.mkdir(parents=True, exist_ok=True)
    keys = [("rollout/ep_return", "episode return (env reward)"), ("disc/accuracy", "discriminator accuracy"),
            ("rollout/bonus", "log q bonus (mean)"), ("perf/sps", "env steps / s")]
    step = np.array([float(r["step"]) for r in rows])
    fig, axes = plt.subplots(1, len(keys), figsize=(4 * len(keys), 3))
    for ax, (k, label) in zip(axes, keys, strict=True):
        if k in rows[0]:
            ax.plot(step, [float(r[k]) if r[k] not in ("", "nan") else np.nan for r in rows])
        ax.set_title(label, fontsize=9)
        ax.set_xlabel("env steps")
    fig.tight_layout()
    fig.savefig(path, dpi=100)
    plt.close(fig)
    return path
