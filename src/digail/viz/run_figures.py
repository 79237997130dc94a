"""Every figure a run folder gets, chosen by its environment (written into RUN/figures/).

`write_run_figures` takes the trained model, the demonstrations with their codes and, optionally, a composition
schedule and a second segmentation to compare with; it rolls out a few closed-loop episodes itself
(`viz.video.play_episodes`, no rendering) and draws:

- all envs: `learning_curves.png` (from metrics.csv), `codes_time.png` (code strips, demonstrations and rollouts),
  `pca_codes.png` (states, first two principal components, coloured by code);
- Four Rooms: `four_rooms_codes.png` (paper Figure 3, one arrow map per code) and `four_rooms_paths.png`;
- 2-D worlds (Circle-World): `generated.png` (by code and by time), `compose.png` under the schedule, and
  `segmentation_pair.png` when two segmentations are given;
- Pendulum: `pendulum_code_map.png` (demonstrations and rollouts).
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from digail.config import FINAL_EVAL_SEED
from digail.viz import figures as F
from digail.viz.video import play_episodes

COMPOSE_SEED_OFFSET = 10_000
"""the composed rollouts start this far past `seed`, so they never replay the closed-loop rollouts' episodes"""


def _obs_dim(obs: np.ndarray) -> int:
    return int(np.prod(np.shape(obs)[1:]))


def composition_figure(episodes: Sequence[tuple[np.ndarray, np.ndarray]], path: Path, schedule_text: str = "",
                       switches: Sequence[Sequence[int]] | None = None, kind: str = "schedule") -> Path:
    """Episodes run under a composed order: paths coloured by code and by time for 2-D observations (the
    reversed-order Circle-World), else code strips; `switches` (the steps at which each episode's next code took
    over, closed-loop orders) are marked on both; `kind` names what `schedule_text` is ("schedule" or "order").
    Written by `digail compose` and by `digail run`."""
    title = f"composition under the {kind} {schedule_text}".strip()
    marks = [list(s) for s in switches] if switches is not None else None
    shown = [(o, c) for o, c in episodes if len(o)]
    if shown and _obs_dim(shown[0][0]) == 2:
        return F.planar_trajectories(shown, path, title=title, switches=marks)
    return F.code_strips({title: [c for _, c in episodes]}, path, switches={title: marks} if marks else None)


def write_run_figures(run_dir: Path, model: Any, env_id: str, demo_obs: Sequence[np.ndarray],
                      demo_codes: Sequence[np.ndarray], *, schedule: Sequence[int] | None = None,
                      schedule_text: str = "",
                      pair: tuple[Sequence[np.ndarray], Sequence[np.ndarray], tuple[str, str], str] | None = None,
                      episodes: int = 6, seed: int = FINAL_EVAL_SEED) -> list[Path]:
    """Draw the run's figures into RUN/figures; returns the paths written.

    Args:
        run_dir: the run folder.
        model: its `HierarchicalPolicy`.
        env_id: the environment it was trained on.
        demo_obs: observations of each demonstration ((T_i + 1, ...) or (T_i, ...)).
        demo_codes: the macro-policy's codes for each demonstration ((T_i,), e.g. from RUN/codes.npz).
        schedule: code per step for the composition figure (None: no composition figure).
        schedule_text: the schedule as the user wrote it, for titles.
        pair: two segmentations of the demonstrations (codes per demonstration, first ones first), the titles of
            their panels and the figure's title, for the side-by-side figure (e.g. the VAE with and without the
            smoothing term).
        episodes: closed-loop rollouts drawn.
        seed: seed of the first rollout (evaluation seeds by default).
    """
    out = Path(run_dir) / "figures"
    paths: list[Path] = []
    rollouts = play_episodes(model, env_id, episodes, seed, render=False)
    gen = [(np.asarray(e.obs), np.asarray(e.codes)) for e in rollouts]
    demos = [(np.asarray(o), np.asarray(c)) for o, c in zip(demo_obs, demo_codes, strict=True)]
    curve = F.learning_curves(run_dir, out / "learning_curves.png")
    if curve is not None:
        paths.append(curve)
    paths.append(F.code_strips({"demonstrations (codes from q)": [c for _, c in demos],
                                "closed-loop rollouts": [c for _, c in gen]}, out / "codes_time.png"))
    paths.append(F.state_pca([o for o, _ in demos + gen], [c for _, c in demos + gen], out / "pca_codes.png",
                             title="demonstration and rollout states (PCA) coloured by code"))
    from digail.envs.registry import env_spec

    dim = _obs_dim(demos[0][0]) if demos else 0
    spec = env_spec(env_id)
    state_figure = spec.state_figure if spec is not None else None
    if state_figure == "four_rooms":
        from digail.envs.four_rooms import decode_observations

        apple = (12, 8)
        if demos:  # the apple of the first demonstration
            x, y = decode_observations(demos[0][0][:1])[1][0]
            apple = (int(x), int(y))
        paths.append(F.four_rooms_code_maps(model, out / "four_rooms_codes.png", apple=apple))
        paths.append(F.four_rooms_trajectories({"expert demonstrations": demos[:4], "closed-loop rollouts": gen[:4]},
                                               out / "four_rooms_paths.png"))
    elif dim == 2:
        paths.append(F.planar_trajectories(gen, out / "generated.png", title="closed-loop rollouts"))
        if schedule is not None:
            composed = play_episodes(model, env_id, episodes, seed + COMPOSE_SEED_OFFSET, schedule=schedule,
                                     render=False)
            paths.append(composition_figure([(np.asarray(e.obs), np.asarray(e.codes)) for e in composed],
                                            out / "compose.png", schedule_text))
    if state_figure == "pendulum" and dim == 3:
        paths.append(F.pendulum_code_map([o for o, _ in demos + gen], [c for _, c in demos + gen],
                                         out / "pendulum_code_map.png"))
    if pair is not None and demos:
        codes_a, codes_b, titles, title = pair
        paths.append(F.segmentation_pair([o for o, _ in demos], list(codes_a), list(codes_b),
                                         out / "segmentation_pair.png", titles=titles, title=title))
    return paths
