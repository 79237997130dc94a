"""The scripted experts solve their tasks exactly: shortest paths in Four Rooms, circles in Circle-World."""

from __future__ import annotations

import gymnasium as gym
import numpy as np
import pytest

import digail  # noqa: F401  (registers the envs)
from digail.envs.four_rooms import APPLE_LABEL, CORRIDORS, FREE_CELLS, ROOMS, FourRoomsEnv, move
from digail.envs.landmark_route import DEMO_ORDER
from digail.envs.registry import ENV_SPECS
from digail.experts.fetch import fetch_expert
from digail.experts.scripted import (
    SCRIPTED_EXPERTS,
    circle_expert,
    evaluate_route_expert,
    four_rooms_expert,
    get_scripted_expert,
    route_expert,
)

# Two apples in every room: a corner cell and an inner cell.
APPLES = [room[0] for room in ROOMS] + [room[len(room) // 2 + 2] for room in ROOMS]


def _distances_from(goal: tuple[int, int]) -> dict[tuple[int, int], int]:
    """Plain BFS over the grid's moves, written independently of `shortest_paths_to`."""
    dist = {goal: 0}
    frontier = [goal]
    while frontier:
        nxt = []
        for cell in frontier:
            for a in range(4):
                new = move(cell, a)
                if new not in dist:
                    dist[new] = dist[cell] + 1
                    nxt.append(new)
        frontier = nxt
    return dist


@pytest.mark.parametrize("apple", APPLES)
def test_four_rooms_expert_takes_a_shortest_path_from_every_start(apple: tuple[int, int]) -> None:
    dist = _distances_from(apple)
    assert set(dist) == set(FREE_CELLS)
    env = gym.make("digail/FourRooms-v0")
    for start in FREE_CELLS:
        if start == apple:
            continue
        _, info = env.reset(seed=0, options={"agent": start, "apple": apple})
        assert info["shortest_path_length"] == dist[start]
        cells, labels = [start], [info["subtask"]]
        terminated = truncated = False
        while not (terminated or truncated):
            _, _, terminated, truncated, info = env.step(four_rooms_expert(env))
            cells.append(env.unwrapped.agent)
            labels.append(info["subtask"])
        assert terminated and info["is_success"]
        assert len(cells) - 1 == dist[start], f"{start} -> {apple}: {len(cells) - 1} steps, BFS {dist[start]}"
        # Each state's label is the next corridor the path actually passes after it, else the apple.
        for t in range(len(cells)):
            ahead = [CORRIDORS.index(c) for c in cells[t + 1 :] if c in CORRIDORS]
            assert labels[t] == (ahead[0] if ahead else APPLE_LABEL), f"{start} -> {apple}, step {t}"


def test_four_rooms_demonstrations_repeat_under_a_seed() -> None:
    def rollout(seed: int) -> list[tuple[int, int]]:
        env = gym.make("digail/FourRooms-v0")
        env.reset(seed=seed)
        cells, done = [env.unwrapped.agent], False
        while not done:
            _, _, terminated, truncated, _ = env.step(four_rooms_expert(env))
            cells.append(env.unwrapped.agent)
            done = terminated or truncated
        return cells

    assert rollout(7) == rollout(7)


def test_circle_expert_draws_the_circle_both_ways() -> None:
    env = gym.make("digail/CircleWorld-v0")
    for seed in range(20):
        obs, info = env.reset(seed=seed)
        r = info["radius"]
        subtasks, positions, total = [info["subtask"]], [obs], 0.0
        done = False
        while not done:
            action = circle_expert(env)
            assert action.dtype == np.float32 and env.action_space.contains(action)
            obs, reward, terminated, truncated, info = env.step(action)
            subtasks.append(info["subtask"])
            positions.append(obs)
            total += reward
            done = terminated or truncated
        assert truncated and not terminated and len(positions) == 121
        assert info["order_correct"] and not info["order_reversed"]
        assert info["radius_error"] < 0.02 and info["closure_error"] < 0.05
        path = np.array(positions, dtype=np.float64)
        np.testing.assert_allclose(np.hypot(path[:, 0], path[:, 1] - r), r, atol=1e-5)
        assert total > -1e-3  # reward = minus the distance to the reference point
        # The label switches exactly once, from 0 (clockwise) to 1 (counter-clockwise), at step 60.
        assert subtasks == [0] * 60 + [1] * 61


@pytest.mark.parametrize("order", [DEMO_ORDER, (3, 2, 1, 0), (2, 0, 1), (1, 3, 0, 2, 1)])
def test_route_expert_drives_any_order_with_a_label_per_leg(order: tuple[int, ...]) -> None:
    """Every leg in turn, never touching a landmark out of turn, the label naming the landmark it heads for."""
    env = gym.make("digail/LandmarkRoute-v0", order=order, max_episode_steps=100 * len(order))
    for seed in range(10):
        _, info = env.reset(seed=seed)
        labels, done = [info["subtask"]], False
        while not done:
            action = route_expert(env)
            assert action.dtype == np.float32 and env.action_space.contains(action)
            _, _, terminated, truncated, info = env.step(action)
            labels.append(info["subtask"])
            done = terminated or truncated
        assert terminated and info["is_success"] and info["legs_done"] == len(order)
        runs = [lb for i, lb in enumerate(labels) if i == 0 or lb != labels[i - 1]]
        assert tuple(runs) == order
        if order == DEMO_ORDER:
            assert len(labels) - 1 >= 150  # three Fetch episodes or more


def test_route_expert_score_over_100_episodes() -> None:
    """The expert's score the docs quote (100 evaluation episodes from seed 10 000, the demonstrated order)."""
    result = evaluate_route_expert(100)
    assert result["success_rate"] == 1.0 and result["wrong_visits"] == 0
    assert result["mean"] == pytest.approx(-286.14, abs=0.01) and result["min_length"] >= 150


def test_get_scripted_expert_mapping() -> None:
    assert get_scripted_expert("digail/FourRooms-v0") is four_rooms_expert
    assert get_scripted_expert("digail/CircleWorld-v0") is circle_expert
    assert get_scripted_expert("digail/FetchPickAndPlace-v4") is fetch_expert
    assert get_scripted_expert("digail/LandmarkRoute-v0") is route_expert
    assert get_scripted_expert("Hopper-v5") is None
    assert get_scripted_expert("CartPole-v1") is None  # an env without a registry entry
    # every scripted expert drives an env the registry knows
    assert SCRIPTED_EXPERTS and all(env_id in ENV_SPECS for env_id in SCRIPTED_EXPERTS)


def test_expert_refuses_the_wrong_env() -> None:
    env = FourRoomsEnv()
    env.reset(seed=0)
    with pytest.raises(TypeError):
        circle_expert(env)
