"""Checks of the synthetic environments: API conformance, seeding, labels, rendering, drawing scores."""

from __future__ import annotations

import math
import warnings

import gymnasium as gym
import numpy as np
import pytest
from gymnasium.utils.env_checker import check_env

import digail  # noqa: F401  (registers the envs)
from digail.envs.circle_world import (
    SCORE_KEYS,
    CircleWorldEnv,
    circle_scores,
    fit_circle_radius,
    reference_point,
)
from digail.envs.four_rooms import (
    APPLE_LABEL,
    CORRIDORS,
    FREE_CELLS,
    ROOMS,
    WALLS,
    FourRoomsEnv,
    decode_observations,
    encode_observation,
    room_of,
    shortest_paths_to,
)
from digail.envs.landmark_route import DEMO_ORDER, REACH, LandmarkRouteEnv, parse_order
from digail.errors import UserError

ENV_IDS = ["digail/FourRooms-v0", "digail/CircleWorld-v0", "digail/LandmarkRoute-v0"]


@pytest.mark.parametrize("env_id", ENV_IDS)
def test_env_checker_passes(env_id: str) -> None:
    env = gym.make(env_id, render_mode="rgb_array")
    # The checker reports API problems as warnings; treat every one as a failure.
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        check_env(env.unwrapped)


@pytest.mark.parametrize("env_id", ENV_IDS)
def test_reset_is_deterministic_under_a_seed(env_id: str) -> None:
    env = gym.make(env_id)
    obs_a, info_a = env.reset(seed=123)
    obs_b, info_b = env.reset(seed=123)
    np.testing.assert_array_equal(obs_a, obs_b)
    assert info_a == info_b
    # Different seeds should not all give the same start (Circle-World: same position, different radius).
    starts = {repr(env.reset(seed=s)) for s in range(10)}
    assert len(starts) > 1


@pytest.mark.parametrize("env_id", ENV_IDS)
def test_render_returns_rgb_uint8(env_id: str) -> None:
    env = gym.make(env_id, render_mode="rgb_array")
    env.reset(seed=0)
    env.step(env.action_space.sample())
    image = env.render()
    assert isinstance(image, np.ndarray) and image.dtype == np.uint8
    assert image.ndim == 3 and image.shape[2] == 3 and min(image.shape[:2]) >= 64
    assert len(np.unique(image.reshape(-1, 3), axis=0)) >= 3  # background, walls/path, agent


@pytest.mark.parametrize("env_id", ENV_IDS)
def test_subtask_in_info_at_reset_and_every_step(env_id: str) -> None:
    """Every step's `info["subtask"]` is one of the labels the env's registry entry names (what the segmentation
    metrics score against), an int from reset on, under random actions; the expert's episode, which does the task,
    runs through two labels or more, each once (a label left is never taken up again), and ends in the last one."""
    import itertools

    from digail.envs.registry import env_spec
    from digail.experts.scripted import get_scripted_expert

    labels = range(len(env_spec(env_id).labels))
    env = gym.make(env_id)
    env.action_space.seed(0)
    _, info = env.reset(seed=0)
    seen = [info["subtask"]]
    done = False
    while not done:
        _, _, terminated, truncated, info = env.step(env.action_space.sample())
        seen.append(info["subtask"])
        done = terminated or truncated
    assert all(type(s) is int and s in labels for s in seen), sorted(set(seen))
    expert = get_scripted_expert(env_id)
    assert expert is not None
    _, info = env.reset(seed=1)
    seen, done = [info["subtask"]], False
    while not done:
        _, _, terminated, truncated, info = env.step(expert(env))
        seen.append(info["subtask"])
        done = terminated or truncated
    runs = [label for label, _ in itertools.groupby(seen)]
    assert len(runs) >= 2 and len(set(runs)) == len(runs) and runs[-1] == labels[-1], runs


def test_registered_time_limits() -> None:
    assert gym.spec("digail/FourRooms-v0").max_episode_steps == 64
    assert gym.spec("digail/CircleWorld-v0").max_episode_steps == 120
    assert gym.spec("digail/LandmarkRoute-v0").max_episode_steps == 400


# --- Four Rooms ----------------------------------------------------------------------------------------


def test_four_rooms_layout() -> None:
    assert WALLS.shape == (11, 15)
    assert len(FREE_CELLS) == 4 * 24 + 4
    assert [len(room) for room in ROOMS] == [24, 24, 24, 24]
    for label, (x, y) in enumerate(CORRIDORS):
        assert not WALLS[y, x] and room_of((x, y)) is None
        # Corridor i joins room i and room i + 1.
        neighbour_rooms = {room_of((x + dx, y + dy)) for dx, dy in ((0, -1), (1, 0), (0, 1), (-1, 0))}
        assert neighbour_rooms - {None} == {label, (label + 1) % 4}


def test_four_rooms_observation_encoding() -> None:
    env = FourRoomsEnv()
    obs, info = env.reset(seed=0, options={"agent": (2, 7), "apple": (12, 1)})
    assert obs.shape == (52,) and obs.dtype == np.float32 and obs.sum() == 4
    assert np.flatnonzero(obs).tolist() == [2, 15 + 7, 26 + 12, 41 + 1]
    np.testing.assert_array_equal(obs, encode_observation((2, 7), (12, 1)))
    assert info["shortest_path_length"] == shortest_paths_to((12, 1)).distance[7, 2]
    # decoding undoes the encoding for every agent cell (apples in every room)
    cells = sorted(FREE_CELLS)
    apples = [ROOMS[i % len(ROOMS)][0] for i in range(len(cells))]
    obs = np.stack([encode_observation(c, a) for c, a in zip(cells, apples, strict=True)])
    agents, found = decode_observations(obs)
    assert [tuple(a) for a in agents] == cells and [tuple(a) for a in found] == apples


def test_four_rooms_dynamics_and_reward() -> None:
    env = FourRoomsEnv()
    env.reset(seed=0, options={"agent": (1, 1), "apple": (3, 1)})
    _, reward, terminated, _, info = env.step(0)  # up into the outer wall: no move
    assert env.agent == (1, 1) and reward == pytest.approx(-0.01) and not terminated
    assert not info["is_success"]
    env.step(1)
    _, reward, terminated, _, info = env.step(1)
    assert env.agent == (3, 1) and terminated and reward == pytest.approx(1.0)
    assert info["is_success"] and info["subtask"] == APPLE_LABEL and info["shortest_path_length"] == 0


def test_four_rooms_random_apple_in_a_room_and_start_elsewhere() -> None:
    env = FourRoomsEnv()
    rooms_seen = set()
    for seed in range(200):
        env.reset(seed=seed)
        assert room_of(env.apple) is not None
        assert env.agent in FREE_CELLS and env.agent != env.apple
        rooms_seen.add(room_of(env.apple))
    assert rooms_seen == {0, 1, 2, 3}


def test_four_rooms_labels_name_the_next_corridor() -> None:
    paths = shortest_paths_to((12, 8))  # apple in the bottom-right room (room 2)
    assert paths.subtask[8, 2] == 2  # bottom-left room: through the bottom corridor next
    assert paths.subtask[2, 11] == 1  # top-right room: through the right corridor next
    assert paths.subtask[7, 9] == APPLE_LABEL  # same room
    assert paths.subtask[8, 7] == APPLE_LABEL  # standing in the bottom corridor: no corridor left
    # From the far corner of the top-left room the path uses two corridors; the label is the first one.
    first = int(paths.subtask[1, 1])
    assert first in (0, 3)
    second = {0: 1, 3: 2}[first]
    assert paths.subtask[CORRIDORS[first][1], CORRIDORS[first][0]] == second


def test_four_rooms_bad_options_raise_user_error() -> None:
    env = FourRoomsEnv()
    with pytest.raises(UserError):
        env.reset(options={"apple": (7, 2)})  # a corridor, not a room cell
    with pytest.raises(UserError):
        env.reset(options={"apple": (3, 3), "agent": (0, 0)})  # a wall
    with pytest.raises(UserError):
        shortest_paths_to((0, 0))


# --- Circle-World --------------------------------------------------------------------------------------


def test_circle_world_reference_path_lies_on_the_circle() -> None:
    r = 0.8
    points = np.array([reference_point(r, k) for k in range(121)])
    np.testing.assert_allclose(np.hypot(points[:, 0], points[:, 1] - r), r, atol=1e-12)
    np.testing.assert_allclose(points[0], 0.0, atol=1e-12)
    np.testing.assert_allclose(points[60], 0.0, atol=1e-12)
    np.testing.assert_allclose(points[120], 0.0, atol=1e-12)
    chords = np.linalg.norm(np.diff(points, axis=0), axis=1)
    np.testing.assert_allclose(chords, 2 * r * math.sin(math.pi / 60), rtol=1e-9)
    assert points[1, 0] < 0  # clockwise with y up: the first step goes left
    np.testing.assert_allclose(points[30], points[90])  # the second half retraces the first


def test_circle_world_steps_by_the_chord_length_whatever_the_action_norm() -> None:
    env = CircleWorldEnv()
    _, info = env.reset(seed=0, options={"radius": 1.0})
    assert info["radius"] == 1.0 and info["subtask"] == 0
    obs, *_ = env.step(np.array([0.01, 0.0], dtype=np.float32))
    assert obs[0] == pytest.approx(2 * math.sin(math.pi / 60)) and obs[1] == 0
    obs_before = obs.copy()
    obs, *_ = env.step(np.zeros(2, dtype=np.float32))
    np.testing.assert_array_equal(obs, obs_before)
    with pytest.raises(ValueError):
        env.step(np.array([np.nan, 1.0]))


def test_circle_world_radius_range_and_truncation() -> None:
    env = gym.make("digail/CircleWorld-v0", r_min=0.7, r_max=0.9)
    radii = [env.reset(seed=s)[1]["radius"] for s in range(30)]
    assert min(radii) >= 0.7 and max(radii) <= 0.9 and np.std(radii) > 0.01
    env.action_space.seed(0)
    for t in range(1, 121):
        _, _, terminated, truncated, info = env.step(env.action_space.sample())
        assert not terminated and truncated == (t == 120)
        assert info["subtask"] == int(t >= 60)
        assert set(SCORE_KEYS).issubset(info) == (t == 120)
    with pytest.raises(UserError):
        CircleWorldEnv(r_min=1.0, r_max=0.5)


def test_circle_scores_directions_and_errors() -> None:
    r = 1.2
    reference = np.array([reference_point(r, k) for k in range(121)])
    ok = circle_scores(reference, r)
    assert ok["order_correct"] and not ok["order_reversed"]
    assert ok["radius_error"] < 1e-9 and ok["closure_error"] < 1e-9
    assert ok["area_first"] == pytest.approx(-1.0, abs=0.01) and ok["area_second"] == pytest.approx(
        1.0, abs=0.01
    )

    mirrored = reference * np.array([-1.0, 1.0])  # mirror in x: counter-clockwise first
    flipped = circle_scores(mirrored, r)
    assert flipped["order_reversed"] and not flipped["order_correct"]

    # Twice the radius, drawn correctly: the radius error is |2r - r| / r = 1.
    big = circle_scores(np.array([reference_point(2 * r, k) for k in range(121)]), r)
    assert big["order_correct"] and big["radius_error"] == pytest.approx(1.0, abs=1e-6)

    # Half a circle, then standing still: closures 2r / r and 0, mean 1.
    half = np.array([reference_point(r, min(k, 30)) for k in range(121)])
    assert circle_scores(half, r)["closure_error"] == pytest.approx(1.0, abs=1e-9)

    with pytest.raises(ValueError):
        circle_scores(reference[:100], r)


def test_fit_circle_radius_edge_cases() -> None:
    angles = np.linspace(0, 2 * np.pi, 50, endpoint=False)
    noisy = np.column_stack([3 + 2 * np.cos(angles), -1 + 2 * np.sin(angles)])
    noisy += np.random.default_rng(0).normal(scale=0.01, size=noisy.shape)
    assert fit_circle_radius(noisy) == pytest.approx(2.0, rel=0.01)
    assert fit_circle_radius(np.zeros((10, 2))) == 0.0
    assert math.isinf(fit_circle_radius(np.column_stack([np.arange(10.0), 2 * np.arange(10.0)])))


# --- Landmark route ------------------------------------------------------------------------------------


def _drive(env: LandmarkRouteEnv, stops: list[int]) -> list[dict]:
    """Drive straight to each landmark of `stops` in turn (ignoring the env's order); the infos of every step."""
    infos = []
    for stop in stops:
        while np.linalg.norm(env.landmarks[stop] - env.pos) > REACH and not env.done:
            gap = env.landmarks[stop] - env.pos
            infos.append(env.step((gap / np.linalg.norm(gap)).astype(np.float32))[4])
    return infos


def test_landmark_route_repeats_under_a_seed_and_varies_across_seeds() -> None:
    def rollout(seed: int) -> np.ndarray:
        env = LandmarkRouteEnv()
        obs, _ = env.reset(seed=seed)
        path = [obs]
        rng = np.random.default_rng(0)
        for _ in range(50):
            path.append(env.step(rng.uniform(-1, 1, 2).astype(np.float32))[0])
        return np.array(path)

    np.testing.assert_array_equal(rollout(3), rollout(3))
    assert not np.allclose(rollout(3), rollout(4))  # landmarks and start move with the seed
    first = rollout(3)[0]
    np.testing.assert_allclose(first[2:10].reshape(4, 2), [(1.2, 1.2), (-1.2, 1.2), (-1.2, -1.2), (1.2, -1.2)],
                               atol=0.2)  # each landmark near its corner
    assert np.abs(first[:2]).max() <= 0.2 and not first[10:].any()  # starts near the centre, touching nothing


def test_landmark_route_labels_follow_the_legs_and_the_touch_sensor_marks_arrivals() -> None:
    env = LandmarkRouteEnv()
    _, info = env.reset(seed=0)
    assert info["subtask"] == DEMO_ORDER[0] and info["legs_done"] == 0
    infos = _drive(env, list(DEMO_ORDER))
    labels = [info["subtask"] for info in infos]
    ends = [t for t, info in enumerate(infos) if info["leg_done"]]
    assert len(ends) == 4 and ends[-1] == len(infos) - 1
    # the label changes exactly at the step a leg ends, to the next landmark of the route
    assert [labels[t] for t in ends[:-1]] == list(DEMO_ORDER[1:])
    assert all(labels[t] == labels[t - 1] for t in range(1, len(infos)) if t not in ends)
    assert infos[-1]["is_success"] and infos[-1]["legs_done"] == 4 and env.done
    obs = env._obs()
    assert obs[10 + DEMO_ORDER[-1]] == 1.0 and obs[10:].sum() == 1.0  # the sensor of the landmark it stands on


def test_landmark_route_judges_the_order() -> None:
    """A route never demonstrated is its own task: driving the demonstrated order on it fails, driving it succeeds;
    touching a landmark out of turn fails the episode even when every leg is done afterwards."""
    new = (3, 2, 1, 0)
    env = LandmarkRouteEnv(order=new)
    env.reset(seed=5)
    infos = _drive(env, list(DEMO_ORDER))
    assert not env.done and not infos[-1]["is_success"] and sum(i["wrong_visit"] for i in infos) == 3
    assert [i["legs_done"] for i in infos][-1] == 1  # only landmark 3, the last stop, was its first leg
    env.reset(seed=5)
    infos = _drive(env, list(new))
    assert env.done and infos[-1]["is_success"] and not any(i["wrong_visit"] for i in infos)
    env.reset(seed=5)
    infos = _drive(env, [1, *new])  # a detour to landmark 1 first
    assert env.done and not infos[-1]["is_success"] and sum(i["wrong_visit"] for i in infos) == 1
    gym_env = gym.make("digail/LandmarkRoute-v0", order="2,0,1")
    assert gym_env.unwrapped.order == (2, 0, 1)


def test_landmark_route_draws_a_path_that_leaves_the_view_only_inside_it() -> None:
    env = LandmarkRouteEnv(render_mode="rgb_array")
    env.reset(seed=0)
    background = int((env.render() == 255).all(-1).sum())
    for _ in range(120):  # far off to the south-west, out of the picture
        env.step(np.array([-0.7, -0.7], np.float32))
    image = env.render()
    assert image is not None and abs(int((image == 255).all(-1).sum()) - background) < 2000


def test_landmark_route_bad_orders_raise_user_error() -> None:
    assert parse_order("2, 0,1") == (2, 0, 1) and parse_order([3, 0]) == (3, 0)
    for bad, words in (("", "no legs"), ("a,b", "comma-separated"), ("0,4", "outside 0-3"), ((1, 1, 2), "twice")):
        with pytest.raises(UserError, match=words):
            LandmarkRouteEnv(order=bad)
