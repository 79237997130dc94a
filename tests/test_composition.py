"""Composition draws what it is asked for: the sub-task policies under a schedule or a closed-loop order, not the
macro-policy's order."""

from __future__ import annotations

import gymnasium as gym
import numpy as np
import pytest
import torch

from digail.algos.optim import adam
from digail.errors import UserError
from digail.eval.composition import (
    OrderSwitch,
    compose,
    compose_order,
    demonstrated_lengths,
    parse_order,
    parse_schedule,
    play_order,
)
from digail.nets.mlp import one_hot
from digail.nets.policy import ActionSpec
from digail.nets.vae import HierarchicalPolicy

ENV = "digail/CircleWorld-v0"


def _policies_per_label(demos, steps: int = 600) -> HierarchicalPolicy:
    """Sub-task policies fitted by regression on the oracle labels: code 0 clockwise, code 1 counter-clockwise."""
    torch.manual_seed(0)
    model = HierarchicalPolicy(2, 2, ActionSpec(False, 2))
    model.normalizer.fit(np.concatenate([t.obs for t in demos]))
    obs = model.normalizer(torch.as_tensor(np.concatenate([t.obs[:-1] for t in demos]), dtype=torch.float32))
    acts = torch.as_tensor(np.concatenate([t.acts for t in demos]), dtype=torch.float32)
    codes = torch.eye(2)[torch.as_tensor(np.concatenate([t.subtasks[:-1] for t in demos]))]
    opt = adam(list(model.pi.parameters()), lr=3e-3)
    for _ in range(steps):
        loss = (model.pi.mode(obs, codes) - acts).pow(2).sum(-1).mean()
        opt.zero_grad()
        loss.backward()
        opt.step()
    return model


def test_reversed_schedule_draws_the_reversed_order(circle_demos):
    model = _policies_per_label(circle_demos)
    natural, _ = compose(model, ENV, parse_schedule("0:60,1:60", 2), episodes=6, seed=20_000)
    assert natural["order_correct_rate"] >= 0.8 and natural["order_reversed_rate"] == 0.0
    reversed_, eps = compose(model, ENV, parse_schedule("1:60,0:60", 2), episodes=6, seed=20_000)
    assert reversed_["order_reversed_rate"] >= 0.8 and reversed_["order_correct_rate"] == 0.0
    assert [e.codes[:2] + e.codes[-2:] for e in eps] == [[1, 1, 0, 0]] * 6  # the schedule, not q, chose the codes


# ------------------------------------------------------------------------------------------ closed-loop orders
class _Ramp(gym.Env):
    """Observation t / 10 at step t whatever the action, 10 steps: a state whose crossing of 0.5 is known."""

    observation_space = gym.spaces.Box(-1.0, 2.0, (1,), np.float32)
    action_space = gym.spaces.Box(-1.0, 1.0, (1,), np.float32)

    def reset(self, *, seed=None, options=None):
        super().reset(seed=seed)
        self.t = 0
        return np.zeros(1, np.float32), {}

    def step(self, action):
        self.t += 1
        return np.full(1, self.t / 10, np.float32), 0.0, False, self.t >= 10, {}


def _threshold_q() -> HierarchicalPolicy:
    """q(. | s, c_prev) with argmax 1 exactly when s > 0.55, whatever c_prev, and probabilities within 0.01 of 0 or
    1 at every state of `_Ramp` (one linear layer with set weights)."""
    model = HierarchicalPolicy(1, 2, ActionSpec(False, 1), hidden=())
    with torch.no_grad():
        layer = model.q.net[0]
        layer.weight.copy_(torch.tensor([[0.0, 0.0, 0.0], [100.0, 0.0, 0.0]]))
        layer.bias.copy_(torch.tensor([0.0, -55.0]))
    return model


def test_order_switches_when_q_leaves_the_running_code():
    model = _threshold_q()
    eps, switches = play_order(model, [_Ramp()], [0, 1], episodes=2, seed=0, hold=1)
    # code 0 is left where s = t / 10 first exceeds 0.55, at t = 6; code 1 then runs to the end
    assert [e.codes for e in eps] == [[0] * 6 + [1] * 4] * 2
    assert [s.switch_steps for s in switches] == [[6], [6]] and all(s.completed for s in switches)
    assert [s.switch_by for s in switches] == [["q"], ["q"]] and switches[0].last_over_step is None
    # order 1, 0: q leaves code 1 at once (s < 0.55), but a code's first step is never asked, so the switch is t = 1;
    # the last code 0 is over (per q) from t = 6 on, which is noted and changes nothing
    eps, switches = play_order(model, [_Ramp()], [1, 0], episodes=1, seed=0, hold=1)
    assert eps[0].codes == [1] + [0] * 9 and switches[0].switch_steps == [1] and switches[0].last_over_step == 6
    # hold 3: the third step past 0.55 (t = 8)
    eps, switches = play_order(model, [_Ramp()], [0, 1], episodes=1, seed=0, hold=3)
    assert eps[0].codes == [0] * 8 + [1] * 2 and switches[0].switch_steps == [8]


def test_switch_rule_hold_ignores_flickers_and_lengths_replace_q():
    flicker = [0.0, 0.0, 1.0, 0.0, 0.0, 1.0, 1.0, 1.0]  # q's leave probability of the running code 0, steps 0..7
    one, two = OrderSwitch([0, 2, 1], hold=1), OrderSwitch([0, 2, 1], hold=2)
    assert [one.step(t, p) for t, p in enumerate(flicker)][:3] == [0, 0, 2]  # the one-step flicker at t = 2 ends it
    assert [two.step(t, p) for t, p in enumerate(flicker)] == [0, 0, 0, 0, 0, 0, 2, 2]  # ignored; t = 5, 6 end it
    assert two.switch_steps == [6] and not two.completed
    # code 2's end never seen by q: it runs its demonstrated 3 steps (t = 6, 7, 8), whatever q says
    rule = OrderSwitch([2, 1], hold=1, lengths={2: 3})
    assert [rule.step(t, 1.0 if t % 2 else 0.0) for t in range(6)] == [2, 2, 2, 1, 1, 1]
    assert rule.switch_steps == [3] and rule.switch_by == ["length"]


def test_switch_rule_sums_a_leave_split_over_two_steps():
    """A path passes the end of a sub-task between two steps: q's leave probability split over them (each below
    1/2, as on Circle-World) still ends the sub-task, at the second step, and with a little more on the first
    step at the first; a lone 0.3 does not, nor two that are far apart."""
    rule = OrderSwitch([0, 1])
    assert [rule.step(t, p) for t, p in enumerate([0.0, 0.0, 0.47, 0.21, 0.0, 0.0])] == [0, 0, 0, 1, 1, 1]
    rule = OrderSwitch([0, 1])
    assert [rule.step(t, p) for t, p in enumerate([0.0, 0.0, 0.51, 0.21, 0.0, 0.0])] == [0, 0, 1, 1, 1, 1]
    apart = [0.0, 0.3, 0.0, 0.3, 0.0, 0.3]
    rule = OrderSwitch([0, 1])
    assert [rule.step(t, p) for t, p in enumerate(apart)] == [0] * 6 and rule.switch_steps == []
    # a code's turn starts afresh: the leave probabilities before its first step do not count
    rule = OrderSwitch([0, 1, 0])
    assert [rule.step(t, p) for t, p in enumerate([0.0, 0.9, 0.3, 0.1, 0.45])] == [0, 1, 1, 1, 0]


def test_demonstrated_lengths_lists_codes_q_never_leaves():
    codes = [np.array([0] * 58 + [1] * 62), np.array([0] * 60 + [1] * 60), np.array([0] * 61 + [1] * 59)]
    assert demonstrated_lengths(codes) == {1: 60}  # code 0 always ends by a switch: q knows its end
    assert demonstrated_lengths([np.array([2, 2, 0, 0, 0]), np.array([0, 2, 2, 2])]) == {}  # 2 ends by a switch once


@pytest.mark.parametrize("text, phrase", [("", "empty"), (" , ", "empty"), ("1;0", "cannot read"),
                                          ("0,-1", "cannot read"), ("0,2", "has 2 codes"),
                                          ("1," + "9" * 30, "has 2 codes"), ("1,1", "twice in a row")])
def test_parse_order_rejects_bad_orders(text, phrase):
    with pytest.raises(UserError, match=phrase):
        parse_order(text, 2)
    assert parse_order(" 1, 0 ,1", 2) == [1, 0, 1]


def _policies_and_q_per_label(demos, steps: int = 400) -> HierarchicalPolicy:
    """`_policies_per_label` plus q fitted on the oracle labels (c_{t-1} the previous label, the start input at
    t = 0): what a perfect segmentation would have given."""
    model = _policies_per_label(demos)
    obs = model.normalizer(torch.as_tensor(np.concatenate([t.obs[:-1] for t in demos]), dtype=torch.float32))
    labels = [torch.as_tensor(t.subtasks[:-1]) for t in demos]
    target = torch.cat(labels)
    prev = torch.cat([one_hot(torch.cat([torch.tensor([-1]), lb[:-1]]), 2) for lb in labels])
    opt = adam(list(model.q.parameters()), lr=3e-3)
    for _ in range(steps):
        loss = torch.nn.functional.cross_entropy(model.q(obs, prev), target)
        opt.zero_grad()
        loss.backward()
        opt.step()
    return model


def test_circle_world_reversed_by_order(circle_demos):
    """Closed loop on Circle-World: q alone ends the first circle where the path comes back to the origin; the
    reversed order needs the counter-clockwise circle's demonstrated length, since no demonstration leaves it."""
    model = _policies_and_q_per_label(circle_demos)
    natural, eps = compose_order(model, ENV, [0, 1], episodes=6, seed=20_000, keep_obs=6)
    assert natural["order_completed_rate"] >= 0.8
    # the task's own scales, from the demonstrations: the length of the first circle and the way a step covers
    circle = int(np.median([np.sum(np.asarray(t.subtasks[:-1]) == 0) for t in circle_demos]))
    stride = float(np.median([np.linalg.norm(np.diff(np.asarray(t.obs), axis=0), axis=1).max() for t in circle_demos]))
    for e, steps in zip(eps, natural["switch_steps"], strict=True):
        # the regression-fitted pi closes its circle some steps early or late (how many depends on where the CPU's
        # float kernels round), so the switch is asserted where the task puts it: at the origin (within a stride,
        # at the switch step or the one before), on the first pass by it (the path came no nearer since it left
        # the origin a quarter circle in), past half a circle and before a second circle could end
        if steps:
            s = steps[0]
            dist = np.linalg.norm(np.asarray(e.obs), axis=1)
            assert circle // 2 < s < 2 * circle, (s, circle)
            assert dist[s - 1:s + 1].min() < stride, (s, dist[s - 1:s + 1], stride)
            assert dist[circle // 4:s - 1].min() >= stride, (s, dist[circle // 4:s - 1].min(), stride)
    lengths = demonstrated_lengths([t.subtasks[:-1] for t in circle_demos])
    assert lengths == {1: 60}
    blind, _ = compose_order(model, ENV, [1, 0], episodes=6, seed=20_000)
    assert blind["order_reversed_rate"] == 0.0 and blind["order_completed_rate"] == 0.0  # q never ends code 1
    reversed_, eps = compose_order(model, ENV, [1, 0], episodes=6, seed=20_000, lengths=lengths)
    assert reversed_["order_reversed_rate"] >= 0.8 and reversed_["switch_steps"] == [[60]] * 6
    assert [e.codes[:2] + e.codes[-2:] for e in eps] == [[1, 1, 0, 0]] * 6


def test_new_order_references_do_the_new_order():
    """The scripted references of the new orders: reversed circles, and Four Rooms the long way round."""
    from digail.envs import make_env
    from digail.envs.circle_world import reference_point, reversed_reference_point
    from digail.envs.episodes import play_episodes
    from digail.envs.four_rooms import corridor_entries
    from digail.eval.returns import summarize
    from digail.experts.scripted import FourRoomsRouteExpert, circle_reversed_expert

    # the reversed path is the demonstrated one's second half, then its first
    assert np.allclose(reversed_reference_point(1.0, 10), reference_point(1.0, 70))
    assert np.allclose(reversed_reference_point(1.0, 70), reference_point(1.0, 10))
    env = make_env(ENV)
    out = summarize(play_episodes(env, lambda e, o: circle_reversed_expert(e), 4, 0), ENV)
    assert out["order_reversed_rate"] == 1.0 and out["radius_error"] < 1e-6
    rooms = make_env("digail/FourRooms-v0")
    expert = FourRoomsRouteExpert([3, 2, 1])
    obs, _ = rooms.reset(options={"agent": (2, 2), "apple": (10, 2)})  # room 0 to room 1, not through corridor 0
    path, done = [obs], False
    while not done:
        obs, _, terminated, truncated, info = rooms.step(expert(rooms))
        path.append(obs)
        done = terminated or truncated
    assert info["is_success"] and corridor_entries(np.array(path)) == [3, 2, 1]
    assert corridor_entries(np.array(path[:3])) == []
