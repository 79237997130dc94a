"""The one switch (`digail.algos.fast`): on the reference path no fast piece runs, and the numbers are the fast
path's (the optimiser step bit for bit, the hand-written gradients to float rounding)."""

from __future__ import annotations

import os
import subprocess
import sys

import pytest
import torch

from digail.algos import fast
from digail.algos.fast.step import LeanStep
from digail.algos.optim import adam


def _nets_and_grads(seed: int) -> tuple[list[torch.Tensor], torch.optim.Optimizer]:
    torch.manual_seed(0)
    net = torch.nn.Sequential(torch.nn.Linear(6, 64), torch.nn.Tanh(), torch.nn.Linear(64, 2))
    params = list(net.parameters())
    return params, adam(params, 1e-3)


def _steps(n: int = 30) -> torch.Tensor:
    params, opt = _nets_and_grads(0)
    step = LeanStep(opt, 0.5)
    for i in range(n):
        g = torch.Generator().manual_seed(i)
        for p in params:
            p.grad = torch.randn(p.shape, generator=g)
        step()
    return torch.cat([p.detach().flatten() for p in params])


def test_optimiser_step_reference_gives_the_fast_bits(monkeypatch: pytest.MonkeyPatch) -> None:
    calls: list[int] = []
    step = torch.optim.Adam.step
    monkeypatch.setattr(torch.optim.Adam, "step", lambda self, *a, **k: (calls.append(1), step(self, *a, **k))[1])
    fast_w = _steps(30)
    assert len(calls) == 1, "the fast path should take Adam's own step only to create its state"
    calls.clear()
    with fast.reference():
        assert not fast.enabled()
        ref_w = _steps(30)
    assert len(calls) == 30, "the reference path should take Adam's own step every time"
    assert fast.enabled()
    assert torch.equal(fast_w, ref_w)


def test_ppo_update_follows_the_switch(monkeypatch: pytest.MonkeyPatch) -> None:
    from test_ppo_grad import _batch, _nets  # the PPO gradient tests' nets and batch

    from digail.algos.fast.ppo_grad import PPOGrad
    from digail.algos.ppo import ppo_update
    from digail.config import PPOConfig

    spy: list[int] = []
    call = PPOGrad.__call__
    monkeypatch.setattr(PPOGrad, "__call__", lambda self, *a: (spy.append(1), call(self, *a))[1])

    def run() -> torch.Tensor:
        pi, v = _nets(None)
        opt = adam([*pi.parameters(), *v.parameters()], 1e-3)
        batch = _batch(pi, 256, torch.Generator().manual_seed(1), spread=0.1)
        ppo_update(pi, v, opt, batch, PPOConfig(epochs=2, minibatch_size=64), torch.Generator().manual_seed(0))
        return torch.cat([p.detach().flatten() for p in [*pi.parameters(), *v.parameters()]])

    fast_w = run()
    assert spy, "the fast path did not take the hand-written gradient"
    spy.clear()
    with fast.reference():
        ref_w = run()
    assert not spy, "the reference path took the hand-written gradient"
    torch.testing.assert_close(fast_w, ref_w, rtol=0, atol=1e-6)


def test_environment_variable_turns_the_fast_path_off() -> None:
    code = "from digail.algos import fast; print(fast.enabled())"
    for value, expected in (("1", "False"), ("0", "True")):
        out = subprocess.run([sys.executable, "-c", code], env=dict(os.environ, DIGAIL_REFERENCE=value),
                             capture_output=True, text=True, check=True).stdout.strip()
        assert out == expected
