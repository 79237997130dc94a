"""PPO pieces: GAE against a hand computation (truncation included) and the update's direction."""

import torch

from digail.algos.ppo import PPOBatch, compute_gae, ppo_update
from digail.config import PPOConfig
from digail.nets.critic import ValueNet
from digail.nets.policy import ActionSpec, SubtaskPolicy


def test_gae_matches_hand_computation_with_termination_and_truncation():
    gamma, lam = 0.9, 0.8
    # One env, 4 steps: episode A ends by *truncation* after step 1 (its final obs is worth 5.0),
    # episode B is *terminated* after step 2, episode C runs past the rollout (bootstrap with last value 3.0).
    rews = torch.tensor([[1.0], [2.0], [0.5], [1.5]])
    values = torch.tensor([[0.4], [0.3], [0.2], [0.1]])
    term = torch.tensor([[False], [False], [True], [False]])
    trunc = torch.tensor([[False], [True], [False], [False]])
    final_values = torch.tensor([[0.0], [5.0], [0.0], [0.0]])
    last = torch.tensor([3.0])
    adv, ret = compute_gae(rews, values, term, trunc, final_values, last, gamma, lam)

    d3 = 1.5 + gamma * 3.0 - 0.1
    a3 = d3
    d2 = 0.5 + 0.0 - 0.2  # terminal: nothing after it
    a2 = d2
    d1 = 2.0 + gamma * 5.0 - 0.3  # truncated: bootstrap the true final observation, not values[2]
    a1 = d1
    d0 = 1.0 + gamma * 0.3 - 0.4
    a0 = d0 + gamma * lam * a1
    expected = torch.tensor([[a0], [a1], [a2], [a3]])
    assert torch.allclose(adv, expected, atol=1e-6)
    assert torch.allclose(ret, expected + values, atol=1e-6)


def test_ppo_update_raises_probability_of_positive_advantage_actions():
    torch.manual_seed(0)
    policy = SubtaskPolicy(3, 2, ActionSpec(True, 4))
    value = ValueNet(3, 2)
    opt = torch.optim.Adam([*policy.parameters(), *value.parameters()], lr=1e-2)
    obs = torch.randn(256, 3)
    codes = torch.eye(2)[torch.randint(2, (256,))]
    with torch.no_grad():
        dist = policy.dist(obs, codes)
        acts = dist.sample()
        logp = dist.log_prob(acts)
    adv = (acts == 2).float() * 2 - 1  # action 2 is good, the rest bad
    batch = PPOBatch(obs, codes, acts, logp, adv, torch.zeros(256))
    before = policy.dist(obs, codes).probs[:, 2].mean().item()
    cfg = PPOConfig(epochs=4, minibatch_size=64)
    stats = ppo_update(policy, value, opt, batch, cfg, torch.Generator().manual_seed(0))
    after = policy.dist(obs, codes).probs[:, 2].mean().item()
    assert after > before + 0.1
    assert stats["clip_frac"] > 0  # the clip engaged: the ratio moved past 1 +- 0.2


def _nets(seed: int = 0) -> tuple[SubtaskPolicy, ValueNet]:
    torch.manual_seed(seed)
    return SubtaskPolicy(5, 3, ActionSpec(False, 2)), ValueNet(5, 3)


def _continuous_batch(policy: SubtaskPolicy, n: int = 256) -> PPOBatch:
    g = torch.Generator().manual_seed(1)
    obs, codes = torch.randn(n, 5, generator=g), torch.eye(3)[torch.randint(3, (n,), generator=g)]
    with torch.no_grad():
        acts = policy.mode(obs, codes) + 0.3 * torch.randn(n, 2, generator=g)
        logp, _ = policy.log_prob_entropy(obs, codes, acts)
    return PPOBatch(obs, codes, acts, logp, torch.randn(n, generator=g), torch.randn(n, generator=g))


def test_compiled_update_matches_eager_and_falls_back(monkeypatch):
    """`PPOConfig.compile` gives the eager update's numbers (up to float rounding); where compiling fails the
    update warns once and carries on eagerly."""
    import warnings

    import pytest

    import digail.algos.ppo as ppo_mod
    from digail.algos.optim import adam

    results = []
    for compile_ in (False, True):
        pi, v = _nets()
        opt = adam([{"params": list(pi.parameters())}, {"params": list(v.parameters())}], lr=3e-4)
        cfg = PPOConfig(epochs=2, minibatch_size=64, compile=compile_)
        stats = ppo_update(pi, v, opt, _continuous_batch(pi), cfg, torch.Generator().manual_seed(0))
        results.append((stats, torch.cat([p.detach().flatten() for p in [*pi.parameters(), *v.parameters()]])))
    (eager_stats, eager_w), (comp_stats, comp_w) = results
    assert torch.allclose(eager_w, comp_w, atol=1e-5)
    assert eager_stats["value"] == pytest.approx(comp_stats["value"], rel=1e-4)

    def broken(fn, **kwargs):  # a machine without a working compiler
        def call(*args):
            raise RuntimeError("no C++ compiler")
        return call

    monkeypatch.setattr(torch, "compile", broken)
    ppo_mod.reset_compiled()  # compile afresh with the broken compiler
    pi, v = _nets()
    opt = adam([{"params": list(pi.parameters())}, {"params": list(v.parameters())}], lr=3e-4)
    try:
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            stats = ppo_update(pi, v, opt, _continuous_batch(pi),
                               PPOConfig(epochs=2, minibatch_size=64, compile=True), torch.Generator().manual_seed(0))
    finally:
        ppo_mod.reset_compiled()  # later tests compile with the real compiler again
    assert [str(w.message) for w in caught if "torch.compile failed" in str(w.message)]
    assert len([w for w in caught if "torch.compile failed" in str(w.message)]) == 1
    assert stats["value"] == pytest.approx(eager_stats["value"], rel=1e-6)
