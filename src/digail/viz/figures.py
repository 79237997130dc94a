"""The paper's figures, drawn from arrays (matplotlib, Agg backend, PNG files).

Every function takes plain data (observations, codes, a model for the Four Rooms maps, a run folder for the
learning curves), writes one PNG of a fixed size (`figsize` inches x `DPI`, never cropped, so tests and the
report can rely on the pixel size) and returns its path. Colours: code k is `tab10` colour k everywhere.

- Four Rooms (paper Figure 3): `four_rooms_code_maps` (most likely action of pi under each code in every free
  cell, the apple fixed) and `four_rooms_trajectories` (paths on the grid coloured by the active code).
- Circle-World: `segmentation_pair` (two segmentations of the same demonstrations side by side, e.g. with and
  without the smoothing term), `planar_trajectories` (paths coloured by code and by time; also used for the
  reversed-order composition).
- Continuous control: `code_strips` (codes against time), `pendulum_code_map` (angle against angular velocity),
  `state_pca` (first two principal components of the states, any K).
- Training: `learning_curves` (one run) and `learning_curves_multi` (mean and spread over seeds per method).
- Choosing K: `codes_curve` (the held-out description length against K of `--codes auto`, the chosen K marked).
"""

from __future__ import annotations

import csv
import io
import json
import math
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
import torch  # noqa: E402
from matplotlib.colors import BoundaryNorm, ListedColormap  # noqa: E402

from digail.fsio import atomic_write_bytes  # noqa: E402

DPI = 100
"""Resolution of every figure: a figure of `(w, h)` inches is `(w * DPI, h * DPI)` pixels."""
CODE_CMAP = ListedColormap([plt.get_cmap("tab10")(i) for i in range(10)])
"""Colour of code k is `CODE_CMAP(k % 10)`."""
CODE_NORM = BoundaryNorm(np.arange(-0.5, 10.5), CODE_CMAP.N)

LEARNING_KEYS: tuple[tuple[str, str], ...] = (
    ("rollout/ep_return", "episode return (env reward)"),
    ("eval/mean_return", "evaluation return (closed-loop)"),
    ("eval/normalized_return", "normalised return (agent / expert)"),
    ("derived/normalized_return", "normalised return (training episodes / expert)"),
    ("disc/accuracy", "discriminator accuracy"),
    ("rollout/bonus", "log q bonus per step"),
)
"""Columns of metrics.csv the learning curves show, with their axis titles; absent columns are skipped.
`derived/normalized_return` is not logged: `run_curves` adds it from the training episodes' return and the
expert's mean return in eval.json when the run has no evaluations during training."""


def code_colour(code: int) -> tuple[float, float, float, float]:
    """The colour of `code` in every figure."""
    return CODE_CMAP(int(code) % 10)  # type: ignore[no-any-return]


FIGURE_SOFTWARE = "digail"
"""the PNG `Software` text every figure carries: what tells a figure digail drew from a user's (`is_figure`)"""


def is_figure(path: Path) -> bool:
    """Whether the regular file `path` is a PNG figure digail drew, which `digail report --force` may replace."""
    try:
        with open(path, "rb") as f:
            head = f.read(4096)
    except OSError:
        return False
    return head.startswith(b"\x89PNG\r\n\x1a\n") and b"Software\x00" + FIGURE_SOFTWARE.encode() in head


def _save(fig: Any, path: Path) -> Path:
    """Write `fig` at DPI without cropping (the pixel size is the figure size times DPI), atomically."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=DPI, metadata={"Software": FIGURE_SOFTWARE})
    plt.close(fig)
    atomic_write_bytes(path, buf.getvalue())
    return path


def _code_legend(ax: Any, codes: Sequence[int], loc: str = "best") -> None:
    for c in sorted({int(c) for c in codes}):
        ax.plot([], [], color=code_colour(c), lw=4, label=f"code {c}")
    if len(codes):
        ax.legend(loc=loc, fontsize=7, framealpha=0.8)


# ------------------------------------------------------------------------------------------- Four Rooms
def _draw_rooms(ax: Any) -> None:
    from digail.envs.four_rooms import CORRIDORS, GRID_HEIGHT, GRID_WIDTH, WALLS

    img = np.where(WALLS[..., None], 0.25, 1.0) * np.ones(3)
    for x, y in CORRIDORS:
        img[y, x] = 0.85
    ax.imshow(img, extent=(-0.5, GRID_WIDTH - 0.5, GRID_HEIGHT - 0.5, -0.5), interpolation="nearest")
    ax.set_xticks([])
    ax.set_yticks([])


@torch.no_grad()
def four_rooms_action_table(model: Any, apple: tuple[int, int]) -> tuple[np.ndarray, np.ndarray]:
    """Most likely action of pi(a | s, c) for every code c and free cell s with the apple at `apple`.

    Returns:
        `cells` (N, 2) int array of free cells (x, y) and `actions` (K, N) int array (0 up, 1 right, 2 down,
        3 left).
    """
    from digail.envs.four_rooms import FREE_CELLS, encode_observation

    cells = np.array([c for c in FREE_CELLS if c != tuple(apple)])
    obs = torch.as_tensor(np.stack([encode_observation(tuple(c), apple) for c in cells]))
    device = next(model.parameters()).device
    obs_n = model.normalizer(obs.to(device))
    eye = torch.eye(model.codes, device=device)
    actions = np.stack([model.pi.mode(obs_n, eye[k].expand(len(cells), -1)).reshape(len(cells)).cpu().numpy()
                        for k in range(model.codes)])
    return cells, actions.astype(np.int64)


def four_rooms_code_maps(model: Any, path: Path, apple: tuple[int, int] = (12, 8)) -> Path:
    """Paper Figure 3: one grid per code with an arrow for pi's most likely action in every free cell; the apple
    (red disc) is the same in every panel."""
    cells, actions = four_rooms_action_table(model, apple)
    return four_rooms_arrow_maps(cells, actions, path, apple=apple,
                                 title=f"Four Rooms: sub-task policy per code, apple at {tuple(apple)}")


def four_rooms_arrow_maps(cells: np.ndarray, actions: np.ndarray, path: Path, *, apple: tuple[int, int] | None = None,
                          title: str = "") -> Path:
    """One Four Rooms grid per code with an arrow for the action `actions[k, i]` (0 up, 1 right, 2 down, 3 left) in
    cell `cells[i]` (x, y). Panels two to a row, so that a phone shows each at half its width rather than a
    quarter (K = 4): size 6.4 x (3 ceil(K / 2)) inches."""
    from digail.envs.four_rooms import ACTION_DELTAS

    K = len(actions)
    cols, rows = 2, max(1, math.ceil(K / 2))
    fig, axes = plt.subplots(rows, cols, figsize=(3.2 * cols, 3.0 * rows), squeeze=False)
    deltas = np.array(ACTION_DELTAS, np.float64)
    for k in range(rows * cols):
        ax = axes[k // cols, k % cols]
        _draw_rooms(ax)
        if k >= K:
            ax.axis("off")
            continue
        d = deltas[actions[k]]
        ax.quiver(cells[:, 0] - 0.3 * d[:, 0], cells[:, 1] - 0.3 * d[:, 1], d[:, 0], d[:, 1], color=code_colour(k),
                  angles="xy", scale_units="xy", scale=1 / 0.6, width=0.012, headwidth=4)
        if apple is not None:
            ax.plot(*apple, "o", color="#d62020", ms=9)
        ax.set_title(f"code {k}: most likely action", fontsize=9)
    if title:
        fig.suptitle(title, fontsize=10)
    fig.tight_layout()
    return _save(fig, path)


def four_rooms_trajectories(groups: Mapping[str, Sequence[tuple[np.ndarray, np.ndarray]]], path: Path) -> Path:
    """Paths on the Four Rooms grid coloured by the active code, one panel per group (e.g. expert, generated).

    Args:
        groups: title -> episodes, each `(obs, codes)` with obs (T + 1, 52) or (T, 52) and codes (T,); a panel
            shows its first episodes (each a slightly offset line, start a black star, apple a red disc).
        path: output PNG; size (3.6 * groups) x 3.4 inches.
    """
    from digail.envs.four_rooms import decode_observations

    n = max(len(groups), 1)
    fig, axes = plt.subplots(1, n, figsize=(3.6 * n, 3.4), squeeze=False)
    for ax, (title, episodes) in zip(axes[0], groups.items(), strict=False):
        _draw_rooms(ax)
        used: list[int] = []
        for i, (obs, codes) in enumerate(episodes[:4]):
            cells, apples = decode_observations(obs)
            xy = cells.astype(np.float64) + (i - 1.5) * 0.08
            codes = np.asarray(codes)
            for t in range(min(len(codes), len(xy) - 1)):
                ax.plot(xy[t:t + 2, 0], xy[t:t + 2, 1], color=code_colour(codes[t]), lw=2.2, solid_capstyle="round")
            ax.plot(xy[0, 0], xy[0, 1], "k*", ms=10)
            ax.plot(*apples[0], "o", color="#d62020", ms=8)
            used += list(codes)
        ax.set_title(title, fontsize=9)
        _code_legend(ax, used, loc="lower left")
    fig.tight_layout()
    return _save(fig, path)


# ------------------------------------------------------------------------------------------ Circle-World
def _planar(ax: Any, episodes: Sequence[tuple[np.ndarray, np.ndarray]], by: str = "code") -> Any:
    """Draw 2-D paths: steps coloured by code (`by="code"`) or by time (`by="time"`); returns a mappable."""
    mappable = None
    for obs, codes in episodes:
        xy = np.asarray(obs, np.float64).reshape(len(obs), -1)[:, :2]
        codes = np.asarray(codes)
        n = min(len(codes), len(xy) - 1) if len(xy) > len(codes) else len(codes)
        if by == "time":
            mappable = ax.scatter(xy[:n, 0], xy[:n, 1], c=np.arange(n), cmap="viridis", s=9, linewidths=0)
        else:
            # later codes drawn smaller on top, so a retraced path shows both codes
            for rank, k in enumerate(np.unique(codes[:n])):
                sel = np.flatnonzero(codes[:n] == k)
                ax.scatter(xy[sel, 0], xy[sel, 1], color=code_colour(k), s=max(4, 20 - 8 * rank), linewidths=0)
        ax.plot(xy[0, 0], xy[0, 1], "k*", ms=9)
    ax.set_aspect("equal")
    ax.set_xlabel("x")
    ax.set_ylabel("y")
    return mappable


def segmentation_pair(obs: Sequence[np.ndarray], codes_a: Sequence[np.ndarray], codes_b: Sequence[np.ndarray],
                      path: Path, titles: tuple[str, str] = ("with smoothing", "without smoothing"),
                      episodes: int = 6, title: str = "") -> Path:
    """Two segmentations of the same demonstrations side by side (left `codes_a`, right `codes_b`, each column
    headed by its title): positions coloured by code (2-D observations) above a strip of codes against time per
    episode, the first `episodes` demonstrations; `title` above both. Size 10 x 7 inches."""
    n = min(episodes, len(obs))
    fig, axes = plt.subplots(2, 2, figsize=(10, 7), gridspec_kw={"height_ratios": [3, 2]})
    for col, (codes, name) in enumerate(((codes_a, titles[0]), (codes_b, titles[1]))):
        eps = [(obs[i], codes[i]) for i in range(n)]
        if np.asarray(obs[0]).reshape(len(obs[0]), -1).shape[1] >= 2:
            _planar(axes[0, col], eps)
        else:
            axes[0, col].axis("off")
        axes[0, col].set_title(name, fontsize=9)
        _code_legend(axes[0, col], [int(c) for i in range(n) for c in np.unique(codes[i])])
        _strips(axes[1, col], [np.asarray(codes[i]) for i in range(n)], [f"demo {i}" for i in range(n)])
        axes[1, col].set_title(f"codes against time, demonstrations 0 to {n - 1}", fontsize=8)
    if title:
        fig.suptitle(title, fontsize=9)
    fig.tight_layout()
    return _save(fig, path)


def planar_trajectories(episodes: Sequence[tuple[np.ndarray, np.ndarray]], path: Path, title: str = "",
                        switches: Sequence[Sequence[int]] | None = None) -> Path:
    """Paths in the plane coloured by code (left) and by time (right); `switches[i]` (steps of episode i at which
    a new code took over) drawn as black crosses on both. Size 10 x 4.6 inches."""
    fig, (ax1, ax2) = plt.subplots(1, 2, figsize=(10, 4.6))
    _planar(ax1, episodes)
    ax1.set_title("coloured by code" + (", x: switches" if switches else ""), fontsize=9)
    _code_legend(ax1, [int(c) for _, codes in episodes for c in np.unique(codes)])
    mappable = _planar(ax2, episodes, by="time")
    ax2.set_title("coloured by time", fontsize=9)
    for (obs, _), steps in zip(episodes, switches or [], strict=False):
        xy = np.asarray(obs, np.float64).reshape(len(obs), -1)[:, :2]
        at = [t for t in steps if 0 <= t < len(xy)]
        for ax in (ax1, ax2):
            ax.plot(xy[at, 0], xy[at, 1], "kx", ms=8, mew=1.6)
    if mappable is not None:
        fig.colorbar(mappable, ax=ax2, label="step")
    fig.suptitle(title, fontsize=10)
    fig.tight_layout()
    return _save(fig, path)


# ---------------------------------------------------------------------------------- continuous control
def _strips(ax: Any, codes: Sequence[np.ndarray], names: Sequence[str]) -> None:
    length = max((len(c) for c in codes), default=1)
    for row, c in enumerate(codes):
        ax.imshow(np.asarray(c)[None] % 10, aspect="auto", cmap=CODE_CMAP, norm=CODE_NORM, interpolation="nearest",
                  extent=(0, len(c), row + 0.85, row))
    ax.set_xlim(0, length)
    ax.set_ylim(len(codes), -0.15)
    ax.set_yticks(np.arange(len(codes)) + 0.42, names, fontsize=7)
    ax.set_xlabel("step")


def code_strips(groups: Mapping[str, Sequence[np.ndarray]], path: Path, episodes: int = 8,
                switches: Mapping[str, Sequence[Sequence[int]]] | None = None) -> Path:
    """Codes against time, one strip per episode, one panel per group (e.g. demonstrations, rollouts);
    `switches[group][i]` (steps at which a new code took over in episode i) drawn as black ticks.
    Size 9 x (1 + 0.3 rows) inches, rows counted over all panels."""
    rows = sum(min(episodes, len(v)) for v in groups.values())
    fig, axes = plt.subplots(len(groups), 1, figsize=(9, 1.0 + 0.3 * rows + 0.6 * len(groups)), squeeze=False,
                             gridspec_kw={"height_ratios": [max(1, min(episodes, len(v))) for v in groups.values()]})
    used: list[int] = []
    for ax, (title, codes) in zip(axes[:, 0], groups.items(), strict=True):
        shown = [np.asarray(c) for c in codes[:episodes]]
        _strips(ax, shown, [f"ep {i}" for i in range(len(shown))])
        for row, steps in enumerate(list((switches or {}).get(title) or [])[:len(shown)]):
            for t in steps:
                ax.plot([t, t], [row - 0.1, row + 0.95], color="k", lw=1.5)
        ax.set_title(title, fontsize=9)
        used += [int(k) for c in shown for k in np.unique(c)]
    _code_legend(axes[0, 0], used, loc="upper right")
    fig.tight_layout()
    return _save(fig, path)


def pendulum_code_map(obs: Sequence[np.ndarray], codes: Sequence[np.ndarray], path: Path, title: str = "") -> Path:
    """Pendulum states (obs = cos theta, sin theta, theta dot) as angle against angular velocity, coloured by
    the code active in them. Size 6 x 4.5 inches."""
    th, thd, cs = [], [], []
    for o, c in zip(obs, codes, strict=True):
        o = np.asarray(o, np.float64)[:len(c)]
        th.append(np.arctan2(o[:, 1], o[:, 0]))
        thd.append(o[:, 2])
        cs.append(np.asarray(c)[:len(o)])
    fig, ax = plt.subplots(figsize=(6, 4.5))
    ax.scatter(np.concatenate(th), np.concatenate(thd), c=np.concatenate(cs) % 10, cmap=CODE_CMAP, norm=CODE_NORM,
               s=6, linewidths=0)
    ax.set_xlabel("angle theta (rad, 0 = upright)")
    ax.set_ylabel("angular velocity (rad/s)")
    ax.set_xlim(-math.pi, math.pi)
    _code_legend(ax, [int(k) for c in cs for k in np.unique(c)])
    ax.set_title(title or "Pendulum: code by state", fontsize=10)
    fig.tight_layout()
    return _save(fig, path)


def state_pca(obs: Sequence[np.ndarray], codes: Sequence[np.ndarray], path: Path, title: str = "") -> Path:
    """States projected on their first two principal components, coloured by code (any K, any obs size).
    Size 6 x 4.5 inches."""
    from sklearn.decomposition import PCA

    X = np.concatenate([np.asarray(o, np.float64).reshape(len(o), -1)[:len(c)] for o, c in zip(obs, codes,
                                                                                              strict=True)])
    C = np.concatenate([np.asarray(c)[:len(o)] for o, c in zip(obs, codes, strict=True)])
    fig, ax = plt.subplots(figsize=(6, 4.5))
    if X.shape[1] >= 2 and len(X) >= 2:
        pca = PCA(n_components=2).fit(X)
        Z = pca.transform(X)
        ax.scatter(Z[:, 0], Z[:, 1], c=C % 10, cmap=CODE_CMAP, norm=CODE_NORM, s=6, linewidths=0)
        ev = pca.explained_variance_ratio_
        ax.set_xlabel(f"PC 1 ({100 * ev[0]:.0f}% of variance)")
        ax.set_ylabel(f"PC 2 ({100 * ev[1]:.0f}% of variance)")
    else:
        ax.scatter(X[:, 0], np.zeros(len(X)), c=C % 10, cmap=CODE_CMAP, norm=CODE_NORM, s=6)
    _code_legend(ax, [int(k) for k in np.unique(C)])
    ax.set_title(title or "states (PCA) coloured by code", fontsize=10)
    fig.tight_layout()
    return _save(fig, path)


# -------------------------------------------------------------------------------------- learning curves
def read_metrics(run_dir: Path) -> dict[str, np.ndarray]:
    """RUN/metrics.csv as column -> float array (empty cells NaN); {} when missing or empty."""
    path = Path(run_dir) / "metrics.csv"
    if not path.exists():
        return {}
    with open(path) as f:
        rows = list(csv.DictReader(f))
    if not rows or "step" not in rows[0]:
        return {}
    keys = list(rows[0])

    def num(v: str | None) -> float:
        try:
            return float(v) if v not in (None, "") else math.nan
        except ValueError:
            return math.nan

    return {k: np.array([num(r.get(k)) for r in rows]) for k in keys}


def run_curves(run_dir: Path) -> dict[str, np.ndarray]:
    """`read_metrics`, plus `derived/normalized_return` = training-episode return / the expert's mean return (the
    definition of eval.json's `normalized_return`) when metrics.csv has no `eval/normalized_return` (training ran
    without `train.eval_every`) and eval.json knows the expert's return."""
    metrics = read_metrics(run_dir)
    has_eval = "eval/normalized_return" in metrics and np.isfinite(metrics["eval/normalized_return"]).any()
    if metrics and not has_eval and "rollout/ep_return" in metrics:
        try:
            expert = json.loads((Path(run_dir) / "eval.json").read_text())["expert"]["mean_return"]
        except (FileNotFoundError, json.JSONDecodeError, KeyError, TypeError):
            expert = None
        if isinstance(expert, int | float) and abs(expert) > 1e-6:
            metrics["derived/normalized_return"] = metrics["rollout/ep_return"] / float(expert)
    return metrics


def _final_normalized(run_dir: Path) -> float | None:
    """eval.json's closed-loop normalised return, drawn as the end point of the derived curve."""
    try:
        value = json.loads((Path(run_dir) / "eval.json").read_text()).get("normalized_return")
    except (FileNotFoundError, json.JSONDecodeError, AttributeError):
        return None
    return float(value) if isinstance(value, int | float) else None


def _present(metrics: Mapping[str, np.ndarray]) -> list[tuple[str, str]]:
    return [(k, t) for k, t in LEARNING_KEYS if k in metrics and np.isfinite(metrics[k]).any()]


def learning_curves(run_dir: Path, path: Path | None = None) -> Path | None:
    """Return, normalised return, discriminator accuracy and bonus against env steps for one run.

    Evaluation columns are logged every `train.eval_every` iterations only; their points are joined across the
    gaps. Without them the normalised return is that of the training episodes (`run_curves`), ending in a star at
    the final closed-loop evaluation's. Size (3.4 panels) x 3 inches; None when the run has no metrics.csv.
    """
    metrics = run_curves(run_dir)
    keys = _present(metrics)
    if not keys:
        return None
    path = Path(path) if path is not None else Path(run_dir) / "figures" / "learning_curves.png"
    fig, axes = plt.subplots(1, len(keys), figsize=(3.4 * len(keys), 3.0), squeeze=False)
    step = metrics["step"]
    for ax, (k, label) in zip(axes[0], keys, strict=True):
        ok = np.isfinite(metrics[k])
        ax.plot(step[ok], metrics[k][ok], marker="o" if ok.sum() < 30 else None, ms=3)
        if k in ("eval/normalized_return", "derived/normalized_return"):
            ax.axhline(1.0, color="grey", ls="--", lw=1, label="expert")
            final = _final_normalized(run_dir) if k.startswith("derived") else None
            if final is not None:
                ax.plot(step[ok][-1:], [final], "*", color="#d62020", ms=10, label="final closed-loop evaluation")
            ax.legend(fontsize=7)
        ax.set_title(label, fontsize=9)
        ax.set_xlabel("env steps")
        ax.ticklabel_format(axis="x", style="sci", scilimits=(-3, 4))
    fig.tight_layout()
    return _save(fig, path)


def learning_curves_multi(runs: Mapping[str, Sequence[Path | Mapping[str, np.ndarray]]], path: Path,
                          points: int = 50) -> Path | None:
    """Mean (line) and min-max spread (band) over seeds per method, against env steps.

    A run is its folder (metrics.csv) or its curves already read (`run_curves`' keys, "step" among them).
    Each run's curve is interpolated onto a common grid of `points` steps up to the shortest run of its method
    (no extrapolation). Size (3.6 panels) x 3.2 inches; None when no run has metrics.
    """
    loaded = {m: [dict(r) if isinstance(r, Mapping) else run_curves(r) for r in rs] for m, rs in runs.items()}
    loaded = {m: [x for x in ms if x] for m, ms in loaded.items()}
    loaded = {m: ms for m, ms in loaded.items() if ms}
    keys = [kt for kt in LEARNING_KEYS if any(k in dict(_present(x)) for ms in loaded.values() for x in ms
                                              for k in [kt[0]])]
    if not keys:
        return None
    fig, axes = plt.subplots(1, len(keys), figsize=(3.6 * len(keys), 3.2), squeeze=False)
    drawn = np.zeros(len(keys), np.int64)  # seeds drawn per panel
    for j, (ax, (k, label)) in enumerate(zip(axes[0], keys, strict=True)):
        for i, (method, ms) in enumerate(sorted(loaded.items())):
            curves = []
            for x in ms:
                if k in x and np.isfinite(x[k]).sum() >= 1:
                    ok = np.isfinite(x[k])
                    curves.append((x["step"][ok], x[k][ok]))
            if not curves:
                continue
            end = min(s[-1] for s, _ in curves)
            start = max(s[0] for s, _ in curves)
            grid = np.linspace(start, end, points) if end > start else np.array([start])
            ys = np.stack([np.interp(grid, s, v) for s, v in curves])
            colour = plt.get_cmap("tab10")(i % 10)
            seeds = f"{len(curves)} seed" + ("s" if len(curves) > 1 else "")
            drawn[j] += len(curves)
            ax.plot(grid, ys.mean(0), color=colour, label=f"{method} ({seeds})")
            if len(curves) > 1:
                ax.fill_between(grid, ys.min(0), ys.max(0), color=colour, alpha=0.2, linewidth=0)
        ax.set_title(label, fontsize=9)
        ax.set_xlabel("env steps")
        ax.ticklabel_format(axis="x", style="sci", scilimits=(-3, 4))
    # the legend's seed counts are per panel: show it where the most seeds are drawn (runs known only by their
    # evaluations, from another machine, have no training scalars)
    axes[0, int(np.argmax(drawn))].legend(fontsize=7)
    fig.tight_layout()
    return _save(fig, path)


# --------------------------------------------------------------------------------------------- choosing K
def codes_curve(curves: Mapping[str, Sequence[Mapping[str, Any]]], path: Path, truth: Mapping[str, int] | None = None,
                cols: int = 4) -> Path:
    """One panel per entry of `curves` (a title and the `k_selection` list `--codes auto` writes to config.json:
    dicts with `codes`, `dl_per_step`, `chosen` and `weighed`): the held-out description length in nats per step
    against K, the chosen K as a filled marker, the K left out of the choice hollow, and, where `truth` gives it,
    the true K as a dashed line."""
    n = max(1, len(curves))
    cols = min(cols, n)
    rows = -(-n // cols)
    fig, axes = plt.subplots(rows, cols, figsize=(3.2 * cols, 2.4 * rows), squeeze=False)
    for ax, (name, curve) in zip(axes.flat, curves.items(), strict=False):
        ks = [int(c["codes"]) for c in curve]
        dl = [float(c["dl_per_step"]) for c in curve]
        ax.plot(ks, dl, "o-", color="0.4", ms=4)
        unweighed = [(k, d) for k, d, c in zip(ks, dl, curve, strict=True) if not c.get("weighed", True)]
        if unweighed:  # fits not weighed: codes used too unevenly, or a better fit uses as many codes alike
            ax.plot(*zip(*unweighed, strict=True), "o", mfc="white", mec="0.4", ms=6, label="not weighed")
        for k, d, c in zip(ks, dl, curve, strict=True):
            if c.get("chosen"):
                chosen = int(c.get("chosen_codes", k))
                ax.plot([k], [d], "o", color=code_colour(3), ms=9,
                        label=f"chosen K = {chosen}" + (f" (the fit of {k})" if chosen != k else ""))
        if truth and name in truth:
            ax.axvline(truth[name], color=code_colour(2), ls="--", lw=1, label=f"true K = {truth[name]}")
        ax.set_title(name, fontsize=8)
        ax.set_xticks(ks)
        ax.tick_params(labelsize=7)
        ax.set_xlabel("K", fontsize=7)
        ax.set_ylabel("held-out nats / step", fontsize=7)
        ax.legend(fontsize=6, loc="upper right")
    for ax in axes.flat[len(curves):]:
        ax.axis("off")
    fig.tight_layout()
    return _save(fig, path)
