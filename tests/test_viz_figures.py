"""Every figure function writes a non-empty PNG of the size its docstring promises (figure inches x DPI), and
draws its data: other data give another picture, and each code shown appears in its colour."""

from __future__ import annotations

import csv

import numpy as np
import pytest
import torch
from PIL import Image

from digail.envs.four_rooms import decode_observations, encode_observation
from digail.nets.policy import ActionSpec
from digail.nets.vae import HierarchicalPolicy
from digail.viz import figures as F


def _size(path) -> tuple[int, int]:
    assert path is not None and path.exists() and path.stat().st_size > 1000
    with Image.open(path) as img:
        img.load()
        assert img.format == "PNG"
        arr = np.asarray(img.convert("L"))
        assert arr.min() < 200, "the figure is blank"
        return img.size


def _pixels(path) -> np.ndarray:
    with Image.open(path) as img:
        return np.asarray(img.convert("RGB"), np.int16)


def _has_colour(path, code: int, tol: int = 6) -> bool:
    """Some pixel of the figure is drawn in `code`'s colour."""
    rgb = np.round(np.asarray(F.code_colour(code)[:3]) * 255).astype(np.int16)
    return bool((np.abs(_pixels(path) - rgb).max(axis=-1) <= tol).any())


def _differ(a, b, share: float = 0.002) -> bool:
    """The two figures (same size) differ in more than `share` of their pixels."""
    pa, pb = _pixels(a), _pixels(b)
    return pa.shape == pb.shape and float((pa != pb).any(axis=-1).mean()) > share


def _px(w: float, h: float) -> tuple[int, int]:
    return round(w * F.DPI), round(h * F.DPI)


@pytest.fixture(scope="module")
def rooms_model():
    torch.manual_seed(0)
    return HierarchicalPolicy(52, 4, ActionSpec(True, 4))


def _rooms_episode(rng, steps=12):
    x, y = 2, 2
    obs, codes = [encode_observation((x, y), (12, 8))], []
    for t in range(steps):
        x = min(x + 1, 6) if t % 2 else x
        y = min(y + 1, 4) if t % 2 == 0 else y
        obs.append(encode_observation((x, y), (12, 8)))
        codes.append(int(t >= steps // 2))
    return np.stack(obs), np.array(codes)


def _circle(n=40, k=2):
    t = np.linspace(0, 2 * np.pi, n + 1)
    obs = np.column_stack([np.sin(t), 1 - np.cos(t)])
    return obs, (np.arange(n) * k // n).astype(np.int64)


def test_four_rooms_code_maps_and_action_table(tmp_path, rooms_model):
    cells, actions = F.four_rooms_action_table(rooms_model, (12, 8))
    assert actions.shape == (4, len(cells)) and set(np.unique(actions)) <= {0, 1, 2, 3}
    assert (12, 8) not in {tuple(c) for c in cells}
    path = F.four_rooms_code_maps(rooms_model, tmp_path / "maps.png", apple=(12, 8))
    assert _size(path) == _px(3.2 * 2, 3.0 * 2)  # K = 4: two rows of two


def test_four_rooms_trajectories(tmp_path):
    rng = np.random.default_rng(0)
    eps = [_rooms_episode(rng) for _ in range(3)]
    path = F.four_rooms_trajectories({"expert": eps, "generated": eps[:1]}, tmp_path / "paths.png")
    assert _size(path) == _px(3.6 * 2, 3.4)
    agents, apples = decode_observations(eps[0][0])
    assert tuple(agents[0]) == (2, 2) and tuple(apples[0]) == (12, 8)


def test_segmentation_pair_and_planar(tmp_path):
    eps = [_circle() for _ in range(3)]
    obs = [o for o, _ in eps]
    a = [c for _, c in eps]
    b = [np.zeros_like(c) for c in a]
    assert _size(F.segmentation_pair(obs, a, b, tmp_path / "pair.png")) == _px(10, 7)
    titled = F.segmentation_pair(obs, a, b, tmp_path / "titled.png", titles=("with ($\\lambda_s$ = 0.1)\nscores",
                                                                             "without"), title="two VAEs\nline two")
    assert _size(titled) == _px(10, 7)
    assert _size(F.planar_trajectories(eps, tmp_path / "gen.png", title="t")) == _px(10, 4.6)
    # the content: both codes drawn in their colours on the left, only code 0 on the right; other paths or other
    # codes, another picture
    assert _has_colour(tmp_path / "pair.png", 0) and _has_colour(tmp_path / "pair.png", 1)
    assert not _has_colour(F.segmentation_pair(obs, b, b, tmp_path / "zeros.png"), 1)
    flipped = [1 - c for c in a]
    assert _differ(tmp_path / "pair.png", F.segmentation_pair(obs, flipped, b, tmp_path / "flipped.png"))
    moved = [(o * np.array([1.0, 0.5]), c) for o, c in eps]
    assert _differ(tmp_path / "gen.png", F.planar_trajectories(moved, tmp_path / "moved.png", title="t"))


def test_code_strips_pendulum_and_pca(tmp_path):
    rng = np.random.default_rng(0)
    codes = [rng.integers(0, 4, 50) for _ in range(3)]
    path = F.code_strips({"demonstrations": codes, "rollouts": codes[:2]}, tmp_path / "strips.png")
    assert _size(path) == _px(9, 1.0 + 0.3 * 5 + 0.6 * 2)
    assert all(_has_colour(path, k) for k in range(4))
    shuffled = [rng.permutation(c) for c in codes]
    assert _differ(path, F.code_strips({"demonstrations": shuffled, "rollouts": shuffled[:2]}, tmp_path / "s2.png"))
    theta = rng.uniform(-np.pi, np.pi, (3, 51))
    obs = [np.column_stack([np.cos(t), np.sin(t), rng.normal(size=51)]) for t in theta]
    assert _size(F.pendulum_code_map(obs, codes, tmp_path / "pend.png")) == _px(6, 4.5)
    hopper = [rng.normal(size=(51, 11)) for _ in range(3)]
    assert _size(F.state_pca(hopper, [rng.integers(0, 8, 50) for _ in range(3)], tmp_path / "pca.png")) == _px(6, 4.5)


def _metrics(path, steps, offset=0.0, with_eval=True):
    path.mkdir(parents=True, exist_ok=True)
    keys = ["step", "rollout/ep_return", "disc/accuracy", "rollout/bonus"] + (
        ["eval/mean_return", "eval/normalized_return"] if with_eval else [])
    with open(path / "metrics.csv", "w", newline="") as f:
        w = csv.writer(f)
        w.writerow(keys)
        for i, s in enumerate(steps):
            row = [s, -100 + i + offset, 0.5, -0.6, *([-90 + i, 0.5 + 0.01 * i] if with_eval else [])]
            if with_eval and i % 3:
                row[-2:] = ["", ""]  # evaluation every third iteration only
            w.writerow(row)


def test_learning_curves_single_and_multi(tmp_path):
    runs = {"digail": [tmp_path / "a", tmp_path / "b"], "gail": [tmp_path / "c"]}
    _metrics(runs["digail"][0], range(64, 64 * 20, 64))
    _metrics(runs["digail"][1], range(64, 64 * 18, 64), offset=5)
    _metrics(runs["gail"][0], range(64, 64 * 20, 64), with_eval=False)
    one = F.learning_curves(runs["digail"][0])
    assert one == tmp_path / "a" / "figures" / "learning_curves.png"
    assert _size(one) == _px(3.4 * 5, 3.0)
    assert _size(F.learning_curves(runs["gail"][0], tmp_path / "g.png")) == _px(3.4 * 3, 3.0)
    assert _size(F.learning_curves_multi(runs, tmp_path / "multi.png")) == _px(3.6 * 5, 3.2)
    _metrics(tmp_path / "shifted", range(64, 64 * 20, 64), offset=40)
    assert _differ(one, F.learning_curves(tmp_path / "shifted", tmp_path / "shifted.png"))
    assert F.learning_curves(tmp_path / "nothing") is None
    # without evaluations during training, the normalised return comes from the training episodes and eval.json
    (runs["gail"][0] / "eval.json").write_text('{"normalized_return": 0.9, "expert": {"mean_return": -50.0}}')
    derived = F.run_curves(runs["gail"][0])["derived/normalized_return"]
    assert np.allclose(derived, F.read_metrics(runs["gail"][0])["rollout/ep_return"] / -50.0)
    assert _size(F.learning_curves(runs["gail"][0], tmp_path / "g2.png")) == _px(3.4 * 4, 3.0)
    assert "derived/normalized_return" not in F.run_curves(runs["digail"][0])  # it has evaluations


def test_codes_curve_marks_the_chosen_k_and_the_truth(tmp_path):
    """One panel per curve (two curves: two panels side by side), the chosen K as a large marker; the pixel size
    is the figure size times DPI."""
    curve = [{"codes": k, "dl_per_step": dl, "chosen": k == 3} for k, dl in ((2, 0.5), (3, -1.0), (4, -1.01))]
    path = F.codes_curve({"a": curve, "b": curve}, tmp_path / "k.png", truth={"a": 3})
    assert Image.open(path).size == (2 * 320, 240)
