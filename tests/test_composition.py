"""Composition draws what it is asked for: the sub-task policies under a schedule, not the macro-policy."""

from __future__ import annotations

import numpy as np
import torch

from digail.algos.optim import adam
from digail.eval.composition import compose, parse_schedule
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
