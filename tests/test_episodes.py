"""The one episode loop: several envs at once play exactly the episodes one env plays after another."""

from __future__ import annotations

import numpy as np

import digail  # noqa: F401  (registers the envs)
from digail.envs import make_env
from digail.envs.episodes import Episode, play_batch, play_episodes
from digail.experts.scripted import four_rooms_expert


def test_batched_loop_plays_the_single_env_episodes_in_order() -> None:
    # Four Rooms episodes end after different numbers of steps, so the three envs take new episodes out of step
    single = play_episodes(make_env("digail/FourRooms-v0"), lambda env, obs: four_rooms_expert(env), 7, seed=5,
                           keep=True)
    assert len({ep.length for ep in single}) > 1
    envs = [make_env("digail/FourRooms-v0") for _ in range(3)]
    ended: list[Episode] = []

    def act(envs_now, obs, eps):
        assert len(envs_now) == len(obs) == len(eps)
        return [four_rooms_expert(env) for env in envs_now]

    batched = play_batch(envs, act, 7, seed=5, keep=2, on_episode=ended.append)
    assert [ep.length for ep in batched] == [ep.length for ep in single]
    assert [ep.ret for ep in batched] == [ep.ret for ep in single]
    assert all(a.terminated == b.terminated and a.final_info.keys() == b.final_info.keys()
               for a, b in zip(batched, single, strict=True))
    for a, b in zip(batched[:2], single[:2], strict=True):  # the kept episodes: same observations and actions
        np.testing.assert_array_equal(np.stack(a.obs), np.stack(b.obs))
        assert a.acts == b.acts and len(a.infos) == a.length + 1
    assert all(not ep.obs for ep in batched[2:])
    assert sorted(map(id, ended)) == sorted(map(id, batched))  # each episode reported once, as it ended
