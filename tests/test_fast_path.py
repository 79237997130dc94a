"""The one switch (`digail.algos.fast`): on the reference path no fast piece runs, and the numbers are the fast
path's (the hand-written gradients to float rounding)."""

from __future__ import annotations

import os
import subprocess
import sys
from collections.abc import Callable
from typing import Any, TypeVar

import pytest
import torch

from digail.algos import fast
from digail.algos.optim import adam

T = TypeVar("T")


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


def _fast_then_reference(monkeypatch: pytest.MonkeyPatch, module: Any, name: str, run: Callable[[], T],
                         what: str) -> tuple[T, T]:
    """`run()` on the fast path, which must call `module.name`, then on the reference path, which must not."""
    spy: list[int] = []
    piece = getattr(module, name)
    monkeypatch.setattr(module, name, lambda *a: (spy.append(1), piece(*a))[1])
    fast_out = run()
    assert spy, f"the fast path did not take {what}"
    spy.clear()
    with fast.reference():
        ref_out = run()
    assert not spy, f"the reference path took {what}"
    return fast_out, ref_out


@pytest.mark.parametrize(("hard", "bptt"), [(False, False), (True, False), (False, True), (True, True)])
def test_gumbel_chain_reference_matches_the_fast_chain(monkeypatch: pytest.MonkeyPatch, hard: bool,
                                                       bptt: bool) -> None:
    """The chain step by step through q's module (the reference) gives the fast chain's samples, logits and
    gradients, from the same generator; the reference never enters the fast chain."""
    from digail.algos.fast import gumbel_chain
    from digail.algos.gumbel import gumbel_softmax_chain
    from digail.nets.vae import MacroPolicy

    torch.manual_seed(0)
    q = MacroPolicy(3, 4, hidden=(16, 16))
    obs_n = torch.randn(6, 20, 3)
    weights = torch.randn(6, 20, 4)

    def run() -> list[torch.Tensor]:
        logits, codes = gumbel_softmax_chain(q, obs_n, 0.7, hard, torch.Generator().manual_seed(5), bptt=bptt)
        loss = (logits * weights).sum() + ((codes * weights.flip(-1)).sum(-1) ** 2).sum()
        return [logits.detach(), codes.detach(), *torch.autograd.grad(loss, list(q.parameters()))]

    fast_out, ref_out = _fast_then_reference(monkeypatch, gumbel_chain, "fast_chain", run, "the fast chain")
    for a, b in zip(fast_out, ref_out, strict=True):
        torch.testing.assert_close(a, b, rtol=1e-4, atol=1e-5)


@pytest.mark.parametrize("discrete", [False, True])
def test_polish_reference_matches_the_scripted_step(monkeypatch: pytest.MonkeyPatch, discrete: bool) -> None:
    """`fit_to_codes` on autograd through the modules ends where the scripted loss-and-gradient step ends (both
    take autograd's kernels on the same numbers: the same bits), and the reference never scripts it."""
    import numpy as np

    from digail.algos.fast import polish_grad
    from digail.algos.polish import fit_to_codes
    from digail.data.trajectory import Trajectory
    from digail.nets.policy import ActionSpec
    from digail.nets.vae import HierarchicalPolicy

    rng = np.random.default_rng(0)
    trajs, codes = [], []
    for _ in range(4):
        obs = rng.normal(size=(31, 5)).astype(np.float32)
        acts = rng.integers(0, 3, 30) if discrete else rng.normal(size=(30, 2)).astype(np.float32)
        trajs.append(Trajectory(obs=obs, acts=acts))
        codes.append((obs[:-1, 0] > 0).astype(np.int64))
    spec = ActionSpec(True, 3) if discrete else ActionSpec(False, 2)

    def run() -> torch.Tensor:
        torch.manual_seed(0)
        model = HierarchicalPolicy(5, 2, spec, (32, 32))
        model.normalizer.fit(np.concatenate([t.obs for t in trajs]).astype(np.float64))
        fit_to_codes(model, trajs, codes, 60, 3e-3, q_noise=0.1, q_anticipate=1, seed=0, progress=False,
                     minibatch=32)
        return torch.cat([p.detach().flatten() for p in [*model.pi.parameters(), *model.q.parameters()]])

    fast_w, ref_w = _fast_then_reference(monkeypatch, polish_grad, "step_grads", run, "the scripted polish step")
    assert torch.equal(fast_w, ref_w)


@pytest.mark.parametrize("discrete", [False, True])
def test_rollout_inference_reference_is_the_modules(discrete: bool) -> None:
    """On the reference path the rollouts call pi, V and q through their modules (`ModuleActorCritic`,
    `ModuleCodeNet`); the NumPy snapshots of the fast path give the same actions, log-probabilities, values and
    q logits, the start code (-1) included."""
    import numpy as np

    from digail.algos.fast.inference import ActorCritic, CodeMLP
    from digail.algos.inference import ModuleActorCritic, ModuleCodeNet, actor_critic, code_net
    from digail.nets.critic import ValueNet
    from digail.nets.policy import ActionSpec
    from digail.nets.vae import HierarchicalPolicy

    torch.manual_seed(0)
    spec = ActionSpec(True, 4) if discrete else ActionSpec(False, 3)
    model = HierarchicalPolicy(6, 3, spec, (32, 32), decoder_obs=(1, 5) if discrete else None)
    value = ValueNet(6, 3, (32, 32))
    with torch.no_grad():
        for p in [*model.pi.parameters(), *model.q.parameters()]:
            p.add_(0.5 * torch.randn_like(p))
    assert isinstance(actor_critic(model.pi, value, 6), ActorCritic)
    assert isinstance(code_net(model.q, 6), CodeMLP)
    with fast.reference():
        ref_ac, ref_q = actor_critic(model.pi, value, 6), code_net(model.q, 6)
    assert isinstance(ref_ac, ModuleActorCritic) and isinstance(ref_q, ModuleCodeNet)
    fast_ac, fast_q = ActorCritic(model.pi, value, 6), CodeMLP([model.q.net], 6)
    rng = np.random.default_rng(1)
    obs = rng.normal(size=(9, 6)).astype(np.float32)
    codes = np.array([-1, 0, 1, 2, 0, 1, 2, -1, 0])
    noise = fast_ac.sample_noise(rng, (9,))
    assert ref_ac.sample_noise(np.random.default_rng(2), (9,)).shape == noise.shape
    (acts, logp, v), (r_acts, r_logp, r_v) = fast_ac.sample(obs, codes[::-1] % 3, noise), \
        ref_ac.sample(obs, codes[::-1] % 3, noise)
    np.testing.assert_array_equal(acts, r_acts) if discrete else np.testing.assert_allclose(acts, r_acts, atol=1e-5)
    np.testing.assert_allclose(logp, r_logp, atol=1e-4)
    np.testing.assert_allclose(v, r_v, atol=1e-5)
    np.testing.assert_allclose(fast_ac.value(obs, codes % 3), ref_ac.value(obs, codes % 3), atol=1e-5)
    np.testing.assert_allclose(fast_q(obs, codes), ref_q(obs, codes), atol=1e-5)


def test_training_rollout_on_the_reference_path_builds_no_snapshot(monkeypatch: pytest.MonkeyPatch,
                                                                   circle_demos: list) -> None:
    """A Directed-Info GAIL rollout with the switch on never builds a NumPy snapshot, and stores what the fast
    path's rollout stores (the same seed: codes and actions equal, numbers to float rounding)."""
    import numpy as np

    from digail.algos.directed_info_gail import DirectedInfoGAIL
    from digail.algos.fast import inference
    from digail.config import PPOConfig, TrainConfig
    from digail.nets.policy import ActionSpec
    from digail.nets.vae import HierarchicalPolicy

    built: list[str] = []
    for name in ("ActorCritic", "CodeMLP"):
        cls = getattr(inference, name)
        monkeypatch.setattr(inference, name, lambda *a, cls=cls, name=name: (built.append(name), cls(*a))[1])

    def rollout() -> dict[str, torch.Tensor]:
        torch.manual_seed(0)
        model = HierarchicalPolicy(circle_demos[0].obs.shape[1], 2, ActionSpec(False, 2))
        model.normalizer.fit(np.concatenate([t.obs for t in circle_demos]))
        cfg = TrainConfig(ppo=PPOConfig(num_envs=2, batch_size=160, minibatch_size=80), closed_loop_codes="argmax")
        trainer = DirectedInfoGAIL("digail/CircleWorld-v0", circle_demos, model, cfg, seed=0, progress=False)
        try:
            return trainer.learner.collect()
        finally:
            trainer.close()

    fast_b = rollout()
    assert {"ActorCritic", "CodeMLP"} <= set(built)
    built.clear()
    with fast.reference():
        ref_b = rollout()
    assert not built, f"the reference path built {built}"
    assert torch.equal(fast_b["codes"], ref_b["codes"])
    for key in ("obs", "acts", "logp", "values", "bonus"):
        torch.testing.assert_close(fast_b[key], ref_b[key], rtol=1e-4, atol=1e-4, msg=key)
