"""The BC / L2 term: squared error of pi's mean (continuous) or NLL (discrete) on the expert's (s, c_E) -> a_E."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch
from torch import nn

from digail.algos.aux_losses import bc_loss
from digail.algos.expert_data import ExpertData
from digail.nets.policy import ActionSpec, SubtaskPolicy


def _policy(action: ActionSpec, per_code: list[list[float]]) -> SubtaskPolicy:
    """pi whose net output ignores the 3 observation features and is row c of `per_code` for code c."""
    pi = SubtaskPolicy(3, 2, action)
    pi.net = nn.Linear(3 + 2, action.dim)
    with torch.no_grad():
        pi.net.weight.zero_()
        pi.net.weight[:, 3:] = torch.tensor(per_code).T
        pi.net.bias.zero_()
    return pi


def _expert(acts: torch.Tensor, code: int) -> ExpertData:
    n = len(acts)
    return ExpertData(obs_n=torch.randn(n, 3), acts=acts, disc_in=torch.zeros(n, 0),
                      codes=torch.full((n,), code, dtype=torch.long), replay_codes=np.zeros((1, n), np.int64))


@pytest.mark.parametrize(("code", "expected"), [(0, 0.0), (1, 1.0 + 4.0)])
def test_continuous_bc_is_the_squared_error_of_the_mean_for_the_expert_code(code: int, expected: float) -> None:
    pi = _policy(ActionSpec(False, 2), [[1.0, 2.0], [0.0, 0.0]])  # mean (1, 2) under code 0, (0, 0) under code 1
    expert = _expert(torch.tensor([[1.0, 2.0]]).repeat(16, 1), code)
    loss = bc_loss(pi, expert, torch.eye(2), 8, torch.Generator().manual_seed(0), discrete=False)
    assert loss.item() == pytest.approx(expected)


def test_discrete_bc_is_the_negative_log_likelihood_of_the_expert_action() -> None:
    pi = _policy(ActionSpec(True, 3), [[5.0, 0.0, 0.0], [0.0, 1.0, 2.0]])
    expert = _expert(torch.full((16,), 2, dtype=torch.long), code=1)
    loss = bc_loss(pi, expert, torch.eye(2), 8, torch.Generator().manual_seed(0), discrete=True)
    assert loss.item() == pytest.approx(math.log(1 + math.exp(-1) + math.exp(-2)))
    loss.backward()  # the term trains pi
    assert pi.net.weight.grad is not None and pi.net.weight.grad.abs().sum() > 0
