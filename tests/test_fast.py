"""The rollout's weight snapshots compute what the modules compute."""

import torch

from digail.nets.critic import ValueNet
from digail.nets.fast import ActorCritic, CodeMLP
from digail.nets.mlp import one_hot
from digail.nets.policy import ActionSpec, SubtaskPolicy
from digail.nets.vae import MacroPolicy


def test_code_mlp_matches_module_including_start_code():
    torch.manual_seed(0)
    q = MacroPolicy(5, 3)
    snap = CodeMLP([q.net], 5)
    obs = torch.randn(7, 5)
    prev = torch.tensor([-1, 0, 1, 2, -1, 2, 0])
    assert torch.allclose(snap(obs, prev), q(obs, one_hot(prev, 3)), atol=1e-5)


def test_actor_critic_matches_modules_continuous_and_discrete():
    torch.manual_seed(0)
    for action in (ActionSpec(False, 2), ActionSpec(True, 4)):
        pi, v = SubtaskPolicy(5, 3, action), ValueNet(5, 3)
        ac = ActorCritic(pi, v, 5)
        obs, codes = torch.randn(9, 5), torch.randint(3, (9,))
        acts, logp, value = ac.sample(obs, codes, torch.Generator().manual_seed(1))
        ref_logp, _ = pi.log_prob_entropy(obs, torch.eye(3)[codes], acts)
        assert torch.allclose(logp, ref_logp, atol=1e-5)
        assert torch.allclose(logp, pi.dist(obs, torch.eye(3)[codes]).log_prob(acts), atol=1e-5)
        assert torch.allclose(value, v(obs, torch.eye(3)[codes]), atol=1e-5)
        _, ent = pi.log_prob_entropy(obs, torch.eye(3)[codes], acts)
        assert torch.allclose(ent, pi.dist(obs, torch.eye(3)[codes]).entropy(), atol=1e-5)


def test_actor_critic_handles_a_policy_that_sees_part_of_the_observation():
    torch.manual_seed(0)
    pi, v = SubtaskPolicy(5, 3, ActionSpec(False, 2), obs_slice=(1, 4)), ValueNet(5, 3)
    ac = ActorCritic(pi, v, 5)
    obs, codes = torch.randn(9, 5), torch.randint(3, (9,))
    out = ac(obs, codes)
    assert torch.allclose(out[:, :2], pi.mode(obs, torch.eye(3)[codes]), atol=1e-5)
