"""The rollout's NumPy weight snapshots compute what the modules compute."""

import numpy as np
import pytest
import torch

from digail.algos.directed_info_gail import DirectedInfoGAIL
from digail.algos.fast.inference import ActorCritic, CodeMLP, log_softmax
from digail.config import PPOConfig, TrainConfig
from digail.envs import make_env
from digail.nets.critic import ValueNet
from digail.nets.mlp import one_hot
from digail.nets.policy import ActionSpec, SubtaskPolicy
from digail.nets.vae import HierarchicalPolicy, MacroPolicy


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
    pi, v = SubtaskPolicy(5, 3, ActionSpec(False, 2), decoder_obs=(1, 4)), ValueNet(5, 3)
    ac = ActorCritic(pi, v, 5)
    obs, codes = torch.randn(9, 5), torch.randint(3, (9,))
    out = ac(obs.numpy(), codes.numpy())
    assert _close(out[:, :2], pi.mode(obs, torch.eye(3)[codes]))
    assert _close(out[:, 2], v(obs, torch.eye(3)[codes]))


@pytest.mark.parametrize("env_id, demos_fixture, decoder_obs", [("digail/FourRooms-v0", "rooms_demos", (0, 2)),
                                                           ("digail/CircleWorld-v0", "circle_demos", None)])
def test_rollout_equals_the_modules_step_by_step(env_id, demos_fixture, decoder_obs, request):
    """Every number `collect` stores, recomputed from the torch modules and the envs' own final observations.

    With argmax codes the macro-policy is deterministic, so the test can say which code each state gets: the
    replayed demonstration's code while it lasts (first half of the envs), else argmax q(. | s, c_prev). Episodes
    end inside the rollout (time limits at 64 / 120 steps), so the bonus on the final observation, the start
    code of the next episode and the truncation bootstrap are all checked.
    """
    demos = request.getfixturevalue(demos_fixture)
    torch.manual_seed(0)
    obs_dim = demos[0].obs.shape[1]
    probe = make_env(env_id)
    model = HierarchicalPolicy(obs_dim, 3, ActionSpec.from_space(probe.action_space), decoder_obs=decoder_obs)
    model.normalizer.fit(np.concatenate([t.obs for t in demos]))
    T, N = 150, 4
    cfg = TrainConfig(ppo=PPOConfig(num_envs=N, batch_size=T * N), closed_loop_codes="argmax")
    trainer = DirectedInfoGAIL(env_id, demos, model, cfg, seed=0, progress=False)
    with torch.no_grad():
        for p in [*model.q.parameters(), *model.pi.parameters()]:  # confident, varied codes and actions
            p.add_(0.5 * torch.randn_like(p))
        model.q.net[0].weight[:, obs_dim:] += 3.0 * torch.randn(64, 3)  # the previous code matters

    demo_of: list[list[int]] = [[] for _ in range(N)]  # the demonstration each episode of each env replays
    start = trainer.start_episodes

    def recording_start(idx):
        start(idx)
        for i in idx:
            demo_of[int(i)].append(int(trainer.codes_state.replay_idx[i]))

    finals: dict[tuple[int, int], np.ndarray] = {}
    step, t_now = trainer.envs.step, [0]

    def recording_step(acts):
        out = step(acts)
        for i, (o, _) in out[5].items():
            finals[(t_now[0], i)] = o
        t_now[0] += 1
        return out

    trainer.start_episodes, trainer.envs.step = recording_start, recording_step
    b = trainer.learner.collect()
    done = (b["terminated"] | b["truncated"]).numpy()
    assert done.sum() >= N and b["truncated"].any()

    eye, q, pi, v, norm = trainer.eye, model.q, model.pi, trainer.learner.value, model.normalizer
    flat = b["obs"].reshape(T * N, -1)
    code_1h = eye[b["codes"].reshape(-1)]
    acts = b["acts"].reshape(T * N, *b["acts"].shape[2:])
    with torch.no_grad():
        ref_logp, _ = pi.log_prob_entropy(flat, code_1h, acts)
        assert torch.allclose(b["logp"].reshape(-1), ref_logp, atol=1e-4)
        assert torch.allclose(b["values"].reshape(-1), v(flat, code_1h), atol=1e-4)

    def expected_code(i: int, episode: int, t_ep: int, s_n: torch.Tensor, prev: int) -> tuple[int, float]:
        logq = torch.log_softmax(q(s_n[None], one_hot(torch.tensor([prev]), 3)), -1)[0]
        code = int(logq.argmax())
        seq = trainer.expert.replay_codes[demo_of[i][episode]]
        if i < trainer.n_replay and t_ep < len(seq) and seq[t_ep] >= 0:
            code = int(seq[t_ep])
        return code, float(logq[code])

    with torch.no_grad():
        for i in range(N):
            episode, t_ep = 0, 0
            assert int(b["codes"][0, i]) == expected_code(i, 0, 0, b["obs"][0, i], -1)[0]
            for t in range(T):
                prev, t_ep = int(b["codes"][t, i]), t_ep + 1
                s_n = norm(torch.from_numpy(finals[(t, i)])) if done[t, i] else (
                    b["obs"][t + 1, i] if t + 1 < T else torch.from_numpy(trainer.rollout_state.obs_n[i]))
                code, logq = expected_code(i, episode, t_ep, s_n, prev)
                assert abs(float(b["bonus"][t, i]) - logq) < 1e-4, (i, t)
                if b["truncated"][t, i]:
                    assert abs(float(b["final_values"][t, i]) - float(v(s_n[None], eye[[code]]))) < 1e-4
                else:
                    assert float(b["final_values"][t, i]) == 0.0
                if done[t, i]:
                    episode, t_ep = episode + 1, 0
                    if t + 1 < T:
                        code = expected_code(i, episode, 0, b["obs"][t + 1, i], -1)[0]
                if t + 1 < T:
                    assert int(b["codes"][t + 1, i]) == code, (i, t)
    # the replayed episodes really replay (first half), the others follow q
    assert trainer.n_replay == N // 2 and all(d >= 0 for i in range(N // 2) for d in demo_of[i])


def test_every_log_std_clamp_uses_the_policy_bounds() -> None:
    """The TorchScript gradients repeat `LOG_STD_BOUNDS` (they cannot read module constants): the same range."""
    import inspect
    import re

    from digail.algos.fast import polish_grad, ppo_grad, vae_grad
    from digail.nets.policy import LOG_STD_BOUNDS

    for module in (ppo_grad, vae_grad, polish_grad):
        found = re.findall(r"clamp\(\s*(-?[\d.]+)\s*,\s*(-?[\d.]+)\s*\)", inspect.getsource(module))
        assert found, f"{module.__name__} no longer clamps a log-std: drop it from this check"
        assert {(float(a), float(b)) for a, b in found} == {LOG_STD_BOUNDS}, module.__name__
