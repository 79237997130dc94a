"""PPO's hand-written minibatch gradient (`ppo_grad`) against autograd: the gradients in float64, and whole
`ppo_update` calls on both paths."""

from __future__ import annotations

import copy

import numpy as np
import pytest
import torch
from torch import nn

from digail.algos import fast
from digail.algos.aux_losses import anchor_loss, bc_loss
from digail.algos.expert_data import ExpertData
from digail.algos.fast.mlp import plain_layers
from digail.algos.fast.ppo_grad import PPOGrad, _minibatch_grads
from digail.algos.fast.scripting import scripted
from digail.algos.optim import adam
from digail.algos.ppo import PPOBatch, minibatch_loss, ppo_update
from digail.config import PPOConfig
from digail.nets.critic import ValueNet
from digail.nets.policy import ActionSpec, SubtaskPolicy


def _nets(decoder_obs: tuple[int, int] | None = None, seed: int = 0) -> tuple[SubtaskPolicy, ValueNet]:
    torch.manual_seed(seed)
    return SubtaskPolicy(5, 3, ActionSpec(False, 2), decoder_obs=decoder_obs), ValueNet(5, 3)


def _batch(pi: SubtaskPolicy, n: int, gen: torch.Generator, spread: float = 0.5) -> PPOBatch:
    """A batch whose old log-probabilities sit `spread` (in log-ratio) around pi's, so that some ratios clip."""
    dt = pi.log_std.dtype
    obs = torch.randn(n, 5, generator=gen, dtype=dt)
    codes = torch.eye(3, dtype=dt)[torch.randint(3, (n,), generator=gen)]
    with torch.no_grad():
        acts = pi.mode(obs, codes) + 0.3 * torch.randn(n, 2, generator=gen, dtype=dt)
        logp, _ = pi.log_prob_entropy(obs, codes, acts)
    logp = logp + spread * torch.randn(n, generator=gen, dtype=dt)
    return PPOBatch(obs, codes, acts, logp, torch.randn(n, generator=gen, dtype=dt),
                    torch.randn(n, generator=gen, dtype=dt))


@pytest.mark.parametrize("with_anchor", [False, True])
@pytest.mark.parametrize("log_std_clamped", [False, True])
def test_hand_written_ppo_gradient_matches_autograd_in_float64(with_anchor: bool, log_std_clamped: bool) -> None:
    pi, v = _nets(decoder_obs=(1, 4))
    pi, v = pi.double(), v.double()
    if log_std_clamped:  # one component beyond the clamp: its gradient is zero
        with torch.no_grad():
            pi.log_std[1] = 2.5
    anchor = copy.deepcopy(pi).requires_grad_(False)
    with torch.no_grad():  # the anchor differs from pi, so that its term has a gradient
        for p in anchor.net.parameters():
            p.add_(0.05 * torch.randn_like(p))
    gen = torch.Generator().manual_seed(3)
    batch = _batch(pi, 64, gen)
    x_pi = pi.inputs(batch.obs, batch.codes)
    x_v = torch.cat([batch.obs, batch.codes], -1)
    adv = batch.adv
    clip, vf_coef, ent_coef, anchor_coef = 0.2, 0.5, 0.01, 3.0
    idx = torch.randint(64, (96,), generator=gen)
    x_anchor = x_pi[idx] if with_anchor else x_pi[:0]
    with torch.no_grad():
        target = anchor.net(x_anchor)

    fn = PPOGrad(pi, v)
    assert fn.applies
    params = fn.targets  # the parameters the gradients are set on, in the order they come back
    assert len({id(p) for p in params}) == len(list(pi.parameters())) + len(list(v.parameters()))
    loss, parts, log_ratio = minibatch_loss(pi, v, x_pi, x_v, batch.acts, batch.logp, adv, batch.returns, clip,
                                            vf_coef, ent_coef)
    anchor_part = (pi.net(x_anchor) - target).pow(2).sum(-1).mean() if with_anchor else torch.zeros((), dtype=adv.dtype)
    ref = torch.autograd.grad(loss + anchor_coef * anchor_part, params)

    ratio = log_ratio.exp()
    assert ((ratio - 1).abs() > clip).any() and ((ratio - 1).abs() < clip).any()  # both sides of the clip
    for impl in (_minibatch_grads, scripted(_minibatch_grads)):
        with torch.no_grad():
            grads, got_parts, got_log_ratio = impl(x_pi, x_v, batch.acts, batch.logp, adv, batch.returns, x_anchor,
                                                   target, fn.pi_w, fn.pi_b, pi.log_std, fn.v_w, fn.v_b, clip,
                                                   vf_coef, ent_coef, anchor_coef)
        assert len(grads) == len(ref)
        for g, r in zip(grads, ref, strict=True):
            assert g.shape == r.shape
            torch.testing.assert_close(g, r, rtol=1e-9, atol=1e-12)
        torch.testing.assert_close(got_parts, torch.cat([parts, anchor_part.detach()[None]]), rtol=1e-12, atol=0)
        torch.testing.assert_close(got_log_ratio, log_ratio, rtol=1e-12, atol=1e-14)
    if log_std_clamped:
        assert grads[len(fn.pi_w) * 2][1] == 0


def _run(hand_grad: bool, with_anchor: bool, decoder_obs: tuple[int, int] | None,
         spy: list[int]) -> tuple[dict[str, float], torch.Tensor]:
    pi, v = _nets(decoder_obs)
    anchor = copy.deepcopy(pi).requires_grad_(False)
    with torch.no_grad():
        for p in anchor.net.parameters():
            p.add_(0.02 * torch.randn(p.shape, generator=torch.Generator().manual_seed(9)))
    opt = adam([{"params": list(pi.parameters()), "lr": 1e-3}, {"params": list(v.parameters())}], lr=3e-3, eps=1e-5)
    gen = torch.Generator().manual_seed(0)
    batch = _batch(pi, 256, torch.Generator().manual_seed(1), spread=0.1)
    aux = {"bc": (lambda: torch.zeros(()), 0.0),
           "anchor": (anchor_loss(pi, anchor, batch, 48, gen), 10.0 if with_anchor else 0.0)}
    cfg = PPOConfig(epochs=3, minibatch_size=64, ent_coef=0.01)
    before = len(spy)
    with fast.pinned(hand_grad):
        stats = ppo_update(pi, v, opt, batch, cfg, gen, aux_losses=aux)
    assert (len(spy) > before) == hand_grad  # the path asked for ran
    return stats, torch.cat([p.detach().flatten() for p in [*pi.parameters(), *v.parameters()]])


@pytest.mark.parametrize(("with_anchor", "decoder_obs"), [(False, None), (True, None), (True, (1, 4))])
def test_ppo_update_on_the_hand_written_gradient_ends_where_autograd_does(
        monkeypatch: pytest.MonkeyPatch, with_anchor: bool, decoder_obs: tuple[int, int] | None) -> None:
    spy: list[int] = []
    call = PPOGrad.__call__

    def counted(self: PPOGrad, *args: object) -> object:
        spy.append(1)
        return call(self, *args)  # type: ignore[arg-type]

    monkeypatch.setattr(PPOGrad, "__call__", counted)
    (auto_stats, auto_w), (hand_stats, hand_w) = (_run(h, with_anchor, decoder_obs, spy) for h in (False, True))
    torch.testing.assert_close(hand_w, auto_w, rtol=0, atol=1e-6)  # float32 rounding apart
    assert hand_stats.keys() == auto_stats.keys()
    for k, val in auto_stats.items():
        assert hand_stats[k] == pytest.approx(val, rel=1e-4, abs=1e-6), k
    assert auto_stats["clip_frac"] > 0
    assert (auto_stats["anchor"] > 0) == with_anchor


def test_minibatches_above_the_bound_keep_the_autograd_path(monkeypatch: pytest.MonkeyPatch) -> None:
    """The hand-written gradient runs up to `HAND_GRAD_MAX_ROWS` rows per minibatch and not above (where it does
    not pay); the fast path is on in both runs."""
    from digail.algos.ppo import HAND_GRAD_MAX_ROWS

    spy: list[int] = []
    call = PPOGrad.__call__
    monkeypatch.setattr(PPOGrad, "__call__", lambda self, *a: (spy.append(1), call(self, *a))[1])
    for mb, used in ((HAND_GRAD_MAX_ROWS, True), (HAND_GRAD_MAX_ROWS * 2, False)):
        pi, v = _nets(None)
        opt = adam([*pi.parameters(), *v.parameters()], 1e-3)
        batch = _batch(pi, HAND_GRAD_MAX_ROWS * 2, torch.Generator().manual_seed(1), spread=0.1)
        spy.clear()
        with fast.pinned(True):
            ppo_update(pi, v, opt, batch, PPOConfig(epochs=1, minibatch_size=mb), torch.Generator().manual_seed(0))
        assert bool(spy) == used, mb


def test_other_nets_and_aux_terms_keep_the_autograd_path(monkeypatch: pytest.MonkeyPatch) -> None:
    """A categorical policy, a net that is not a plain `mlp`, or the BC term: `PPOGrad` does not run."""

    def refuse(*args: object) -> None:
        raise AssertionError("hand-written gradient used")

    monkeypatch.setattr(PPOGrad, "__call__", refuse)
    gen = torch.Generator().manual_seed(0)
    cfg = PPOConfig(epochs=1, minibatch_size=64)

    torch.manual_seed(0)
    disc_pi = SubtaskPolicy(5, 3, ActionSpec(True, 4))
    v = ValueNet(5, 3)
    obs, codes = torch.randn(128, 5), torch.eye(3)[torch.randint(3, (128,))]
    acts = torch.randint(4, (128,))
    logp, _ = disc_pi.log_prob_entropy(obs, codes, acts)
    batch = PPOBatch(obs, codes, acts, logp.detach(), torch.randn(128), torch.randn(128))
    ppo_update(disc_pi, v, adam(list(disc_pi.parameters()) + list(v.parameters()), 1e-3), batch, cfg, gen)

    pi, v = _nets()
    pi.net = nn.Sequential(*pi.net[:-1], nn.Tanh(), pi.net[-1])  # type: ignore[index]
    assert plain_layers(pi.net) is None
    batch = _batch(pi, 128, gen)
    ppo_update(pi, v, adam(list(pi.parameters()) + list(v.parameters()), 1e-3), batch, cfg, gen)

    pi, v = _nets()
    expert = ExpertData(obs_n=torch.randn(32, 5), acts=torch.randn(32, 2), disc_in=torch.zeros(32, 0),
                        codes=torch.zeros(32, dtype=torch.long), replay_codes=np.zeros((1, 32), np.int64))
    bc = (lambda: bc_loss(pi, expert, torch.eye(3), 16, gen, discrete=False), 1.0)
    stats = ppo_update(pi, v, adam(list(pi.parameters()) + list(v.parameters()), 1e-3), _batch(pi, 128, gen), cfg,
                       gen, aux_losses={"bc": bc})
    assert stats["bc"] > 0
