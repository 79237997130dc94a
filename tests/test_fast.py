"""The rollout's NumPy weight snapshots compute what the modules compute."""

import numpy as np
import torch

from digail.nets.critic import ValueNet
from digail.nets.fast import ActorCritic, CodeMLP, log_softmax
from digail.nets.mlp import one_hot
from digail.nets.policy import ActionSpec, SubtaskPolicy
from digail.nets.vae import MacroPolicy


def _close(a: np.ndarray, b: torch.Tensor) -> bool:
    return torch.allclose(torch.from_numpy(np.asarray(a)).to(b.dtype), b, atol=1e-5)


def test_code_mlp_matches_module_including_start_code():
    torch.manual_seed(0)
    q = MacroPolicy(5, 3)
    snap = CodeMLP([q.net], 5)
    obs = torch.randn(7, 5)
    prev = torch.tensor([-1, 0, 1, 2, -1, 2, 0])
    out = snap(obs.numpy(), prev.numpy())
    assert out.dtype == np.float32
    assert _close(out, q(obs, one_hot(prev, 3)))
    assert _close(log_softmax(out), torch.log_softmax(q(obs, one_hot(prev, 3)), -1))


def test_code_mlp_of_deeper_nets_matches():
    torch.manual_seed(0)
    pi, v = SubtaskPolicy(5, 3, ActionSpec(False, 2), hidden=(32, 16, 8)), ValueNet(5, 3, hidden=(32, 16, 8))
    snap = CodeMLP([pi.net, v.net], 5)
    obs, codes = torch.randn(6, 5), torch.randint(3, (6,))
    out = snap(obs.numpy(), codes.numpy())
    assert _close(out[:, :2], pi.mode(obs, torch.eye(3)[codes]))
    assert _close(out[:, 2], v(obs, torch.eye(3)[codes]))


def test_actor_critic_matches_modules_continuous_and_discrete():
    torch.manual_seed(0)
    for action in (ActionSpec(False, 2), ActionSpec(True, 4)):
        pi, v = SubtaskPolicy(5, 3, action), ValueNet(5, 3)
        with torch.no_grad():
            for p in [*pi.parameters(), *v.parameters()]:  # out of the near-zero initial head
                p.add_(0.3 * torch.randn_like(p))
        ac = ActorCritic(pi, v, 5)
        obs, codes = torch.randn(9, 5), torch.randint(3, (9,))
        noise = ac.sample_noise(np.random.default_rng(1), (9,))
        acts_np, logp, value = ac.sample(obs.numpy(), codes.numpy(), noise)
        acts = torch.from_numpy(acts_np)
        code_1h = torch.eye(3)[codes]
        ref_logp, _ = pi.log_prob_entropy(obs, code_1h, acts)
        assert _close(logp, ref_logp)
        assert _close(logp, pi.dist(obs, code_1h).log_prob(acts))
        assert _close(value, v(obs, code_1h))
        assert _close(ac.value(obs.numpy(), codes.numpy()), v(obs, code_1h))
        if action.discrete:
            assert acts.dtype == torch.int64
            # Gumbel-max picks the argmax of logits + noise
            logits = pi.net(torch.cat([obs, code_1h], -1))
            assert torch.equal(acts, (torch.log_softmax(logits, -1) + torch.from_numpy(noise)).argmax(-1))
        else:
            mean, std = pi.mode(obs, code_1h), pi.log_std.clamp(-5.0, 2.0).exp()
            assert _close(acts_np, mean + std * torch.from_numpy(noise))


def test_actor_critic_samples_follow_the_policy():
    """Many samples from one state: the empirical action distribution is pi's."""
    torch.manual_seed(0)
    rng = np.random.default_rng(0)
    obs, codes = np.zeros((20000, 5), np.float32), np.zeros(20000, np.int64)
    pi, v = SubtaskPolicy(5, 3, ActionSpec(True, 3)), ValueNet(5, 3)
    with torch.no_grad():
        pi.net[-1].bias.copy_(torch.tensor([0.0, 1.0, -1.0]))
    ac = ActorCritic(pi, v, 5)
    acts, _, _ = ac.sample(obs, codes, ac.sample_noise(rng, (20000,)))
    probs = torch.softmax(pi.net(torch.cat([torch.zeros(1, 5), torch.eye(3)[:1]], -1))[0], -1).detach().numpy()
    np.testing.assert_allclose(np.bincount(acts, minlength=3) / 20000, probs, atol=0.015)
    pi_c = SubtaskPolicy(5, 3, ActionSpec(False, 2))
    ac_c = ActorCritic(pi_c, v, 5)
    acts_c, _, _ = ac_c.sample(obs, codes, ac_c.sample_noise(rng, (20000,)))
    np.testing.assert_allclose(acts_c.std(0), pi_c.log_std.exp().detach().numpy(), rtol=0.03)


def test_actor_critic_handles_a_policy_that_sees_part_of_the_observation():
    torch.manual_seed(0)
    pi, v = SubtaskPolicy(5, 3, ActionSpec(False, 2), obs_slice=(1, 4)), ValueNet(5, 3)
    ac = ActorCritic(pi, v, 5)
    obs, codes = torch.randn(9, 5), torch.randint(3, (9,))
    out = ac(obs.numpy(), codes.numpy())
    assert _close(out[:, :2], pi.mode(obs, torch.eye(3)[codes]))
    assert _close(out[:, 2], v(obs, torch.eye(3)[codes]))
