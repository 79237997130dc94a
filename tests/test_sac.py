"""The off-policy learner (`--train.learner sac`): its update against a hand computation, the hand-written
gradients against autograd, the reward relabelling and the bonus, learning on Pendulum, resume, bad input."""

from __future__ import annotations

import dataclasses
import math

import gymnasium as gym
import numpy as np
import pytest
import torch

from digail.algos.sac import SACBatch, SACUpdate
from digail.config import SACConfig, TrainConfig
from digail.errors import UserError
from digail.imitation_config import ImitationConfig
from digail.nets.policy import ActionSpec, SubtaskPolicy

LOG_2PI = math.log(2 * math.pi)


def _np_mlp(x: np.ndarray, layers: list[tuple[np.ndarray, np.ndarray]]) -> np.ndarray:
    """A ReLU MLP in float64 NumPy from (weight (out, in), bias) pairs: the hand computation's own forward pass."""
    for w, b in layers[:-1]:
        x = np.maximum(x @ w.T + b, 0.0)
    w, b = layers[-1]
    return x @ w.T + b


def _tiny(hand: bool, seed: int = 0) -> tuple[SACUpdate, SACBatch, torch.Tensor, torch.Tensor]:
    """A float64 learner with 2-d observations, K = 2 codes, 1-d actions in [-1, 1], 3-unit nets, and a 3-row
    batch whose last row ends by termination (absorbing value 2.5)."""
    dtype = torch.float64
    torch.manual_seed(seed)
    previous = torch.get_default_dtype()
    torch.set_default_dtype(dtype)
    try:
        pi = SubtaskPolicy(2, 2, ActionSpec(False, 1), (3,))
        with torch.no_grad():
            pi.log_std.fill_(-0.7)
        cfg = SACConfig(hidden=(3,), gamma=0.9, tau=0.1, init_alpha=0.2, lr=1e-2, alpha_lr=1e-2)
        learner = SACUpdate(pi, 2, 2, cfg, lambda a: a.clamp(-1.0, 1.0), torch.device("cpu"),
                             bounds=(np.array([-1.0]), np.array([1.0])) if hand else None)
    finally:
        torch.set_default_dtype(previous)
    with torch.no_grad():  # targets unlike the critics, so the test tells them apart
        for p in learner.critic_target.parameters():
            p.add_(0.3 * torch.randn_like(p))
    eye = torch.eye(2, dtype=dtype)
    g = torch.Generator().manual_seed(1)
    b = SACBatch(obs=torch.randn(3, 2, generator=g, dtype=dtype), code_1h=eye[[0, 1, 1]],
                 acts=torch.tensor([[0.3], [-1.0], [0.8]], dtype=dtype),
                 next_obs=torch.randn(3, 2, generator=g, dtype=dtype), next_code_1h=eye[[1, 1, 0]],
                 terminated=torch.tensor([False, False, True]), rews=torch.tensor([0.5, -0.2, 1.0], dtype=dtype),
                 absorbing_value=torch.tensor(2.5, dtype=dtype))
    noise_next = torch.tensor([[0.4], [3.0], [-0.1]], dtype=dtype)  # row 1's action lands past the bound: clipped
    noise_pi = torch.tensor([[-0.5], [0.2], [4.0]], dtype=dtype)
    return learner, b, noise_next, noise_pi


def _critic_layers(params: list[torch.Tensor], net: int) -> list[tuple[np.ndarray, np.ndarray]]:
    n = len(params) // 2
    return [(params[i][net].detach().numpy().T, params[n + i][net, 0].detach().numpy()) for i in range(n)]


@pytest.mark.parametrize("hand", [False, True])
def test_update_matches_a_hand_computation(hand):
    learner, b, noise_next, noise_pi = _tiny(hand)
    pi = learner.pi
    pi_layers = [(m.weight.detach().numpy().copy(), m.bias.detach().numpy().copy())
                 for m in pi.net if isinstance(m, torch.nn.Linear)]
    q_old = [p.detach().clone() for p in learner.critic.parameters()]
    t_old = [p.detach().clone() for p in learner.critic_target.parameters()]
    log_std, alpha = -0.7, 0.2
    obs, c, a = b.obs.numpy(), b.code_1h.numpy(), b.acts.numpy()
    nobs, nc = b.next_obs.numpy(), b.next_code_1h.numpy()
    entropy = log_std + 0.5 * (1 + LOG_2PI)  # one action dimension

    # target: r + gamma (min Q'(s', c', clip(mu' + std eps)) + alpha H), or r + gamma V_abs at the termination
    a_next = np.clip(_np_mlp(np.concatenate([nobs, nc], 1), pi_layers) + math.exp(log_std) * noise_next.numpy(),
                     -1, 1)
    x_next = np.concatenate([nobs, nc, a_next], 1)
    q_next = np.minimum(*(_np_mlp(x_next, _critic_layers(t_old, i))[:, 0] for i in range(2)))
    v_next = np.where([False, False, True], 2.5, q_next + alpha * entropy)
    target = b.rews.numpy() + 0.9 * v_next
    assert a_next[1, 0] == 1.0  # the clip is exercised
    x = np.concatenate([obs, c, a], 1)
    q = [_np_mlp(x, _critic_layers(q_old, i))[:, 0] for i in range(2)]
    q_loss = 0.5 * sum(((qi - target) ** 2).mean() for qi in q)

    stats = learner.update(b, noise_next, noise_pi).numpy()
    assert stats[0] == pytest.approx(q_loss, rel=1e-9)
    assert stats[3] == pytest.approx(alpha) and stats[4] == pytest.approx(entropy)
    assert stats[5] == pytest.approx(np.mean(q), rel=1e-9)

    # the policy's loss is taken against the critics after their step
    q_new = [p.detach().clone() for p in learner.critic.parameters()]
    a_pi = np.clip(_np_mlp(np.concatenate([obs, c], 1), pi_layers) + math.exp(log_std) * noise_pi.numpy(), -1, 1)
    x_pi = np.concatenate([obs, c, a_pi], 1)
    q_pi = np.minimum(*(_np_mlp(x_pi, _critic_layers(q_new, i))[:, 0] for i in range(2)))
    assert stats[1] == pytest.approx(-q_pi.mean() - alpha * entropy, rel=1e-9)

    # temperature: loss log alpha (H - H_target), H_target = -1; Adam's first step moves log alpha by lr against
    # the sign of H - H_target (here positive: alpha falls)
    assert stats[2] == pytest.approx(math.log(alpha) * (entropy + 1.0), rel=1e-9)
    assert learner.log_alpha.item() == pytest.approx(math.log(alpha) - 1e-2, rel=1e-6)
    # targets: Polyak step tau = 0.1 towards the updated critics
    for t_before, q_after, t_after in zip(t_old, q_new, learner.critic_target.parameters(), strict=True):
        torch.testing.assert_close(t_after.detach(), t_before + 0.1 * (q_after - t_before))


def test_hand_gradients_equal_autograd():
    """Three updates of each path from the same start give the same weights (float64); the hand path's first
    update creates the optimisers' state in pieces, the next two run as one scripted call."""
    runs = []
    for hand in (False, True):
        learner, b, noise_next, noise_pi = _tiny(hand, seed=3)
        assert learner.hand == hand
        for _ in range(3):
            learner.update(b, noise_next, noise_pi)
        assert learner.fused_updates == (2 if hand else 0)
        runs.append([p.detach().clone() for p in (*learner.critic.parameters(), *learner.pi.parameters(),
                                                  learner.log_alpha)])
    for p_auto, p_hand in zip(*runs, strict=True):
        torch.testing.assert_close(p_hand, p_auto, rtol=1e-10, atol=1e-12)


def _all_weights(learner: SACUpdate) -> list[torch.Tensor]:
    return [p.detach().clone() for p in (*learner.critic.parameters(), *learner.critic_target.parameters(),
                                         *learner.pi.parameters(), learner.log_alpha)]


@pytest.mark.parametrize("train_policy", [True, False])
def test_one_scripted_update_gives_the_bits_of_the_pieces(train_policy):
    """`sac_update` (gradients, the three fused Adam steps and the Polyak step in one call) against the same
    gradients with torch's own optimiser steps: identical weights, optimiser state and stats after four updates."""
    runs = []
    for fused in (False, True):
        learner, b, noise_next, noise_pi = _tiny(True, seed=5)
        stats = []
        for i in range(4):
            with torch.no_grad():
                if fused:
                    stats.append(learner.update(b, noise_next, noise_pi, train_policy=train_policy or i == 0))
                else:
                    stats.append(learner._update_hand_steps(b, noise_next, noise_pi, train_policy or i == 0))
        assert learner.fused_updates == (3 if fused else 0)
        opt_state = [t.clone() for o in (learner.q_optimizer, learner.pi_optimizer, learner.alpha_optimizer)
                     for st in o.state.values() for t in st.values()]
        runs.append((_all_weights(learner), opt_state, stats))
    for a, b in zip(runs[0][0] + runs[0][1], runs[1][0] + runs[1][1], strict=True):
        assert torch.equal(a, b)
    for a, b in zip(runs[0][2], runs[1][2], strict=True):
        assert torch.equal(a, b)


def test_fast_functions_compile_to_torchscript():
    """Each scripted piece really is TorchScript: where scripting fails, `scripted` falls back to the Python
    function (the same numbers, several times slower), which no other test would notice."""
    from digail.algos.fast import mlp, sac_grad
    from digail.algos.fast.scripting import scripted

    for fn in (sac_grad.critic_grads, sac_grad.policy_grads, sac_grad.sac_update, sac_grad.disc_grads,
               sac_grad.disc_update, mlp.output):
        compiled = scripted(fn)
        # the fallback hands back the Python function itself; a scripted one has a TorchScript graph of its own
        assert compiled is not fn and list(compiled.graph.nodes()), fn.__name__
    # and it computes what the Python function does
    torch.manual_seed(0)
    x = torch.randn(5, 3)
    w, b = [torch.randn(4, 3), torch.randn(2, 4)], [torch.randn(4), torch.randn(2)]
    torch.testing.assert_close(scripted(mlp.output)(x, w, b), mlp.output(x, w, b), rtol=1e-6, atol=1e-6)


def test_policy_warmup_holds_the_policy_still():
    learner, b, noise_next, noise_pi = _tiny(True)
    before = [p.detach().clone() for p in learner.pi.parameters()]
    alpha = learner.log_alpha.item()
    learner.update(b, noise_next, noise_pi, train_policy=False)
    assert all(torch.equal(p0, p) for p0, p in zip(before, learner.pi.parameters(), strict=True))
    assert learner.log_alpha.item() == alpha


def test_replay_rows_hold_each_transition_and_wrap_around():
    from digail.algos.replay import ReplayBuffer

    buf = ReplayBuffer(5, obs_dim=2, act_dim=1, codes=3)
    rng = np.random.default_rng(0)

    def batch(n: int) -> dict[str, np.ndarray]:
        return {"obs": rng.normal(size=(n, 2)).astype(np.float32), "codes": rng.integers(0, 3, n),
                "acts": rng.normal(size=(n, 1)).astype(np.float32),
                "next_obs": rng.normal(size=(n, 2)).astype(np.float32), "next_codes": rng.integers(0, 3, n),
                "terminated": rng.random(n) < 0.5, "bonus": rng.normal(size=n).astype(np.float32),
                "rews": rng.normal(size=n).astype(np.float32)}

    first, second = batch(3), batch(4)
    buf.add(**first)
    buf.add(**second)  # rows 3, 4, then 0, 1
    assert (buf.pos, buf.size) == (2, 5)
    order = [5, 6, 2, 3, 4]  # what each row holds, counted over both batches
    every = {k: np.concatenate([first[k], second[k]]) for k in first}
    b = buf.get(torch.tensor([0, 1, 2, 3, 4]))
    for name in ("obs", "acts", "next_obs", "bonus", "rews"):
        np.testing.assert_array_equal(b[name].numpy(), every[name][order])
    np.testing.assert_array_equal(b["terminated"].numpy(), every["terminated"][order])
    np.testing.assert_array_equal(b["code_1h"].numpy(), np.eye(3)[every["codes"][order]])
    np.testing.assert_array_equal(b["next_code_1h"].numpy(), np.eye(3)[every["next_codes"][order]])
    # [s, c, a], the critics' input, is one slice of a gathered row
    row = buf.gather(torch.tensor([3]))[0, :6].numpy()
    np.testing.assert_array_equal(row, np.concatenate([every["obs"][3], np.eye(3)[every["codes"][3]],
                                                       every["acts"][3]]))
    again = ReplayBuffer(5, obs_dim=2, act_dim=1, codes=3)
    again.load_state_dict(buf.state_dict())
    assert (again.pos, again.size) == (2, 5)
    np.testing.assert_array_equal(again.table, buf.table)
    np.testing.assert_array_equal(again.next_codes, buf.next_codes)
    with pytest.raises(UserError, match="codes"):
        ReplayBuffer(5, obs_dim=2, act_dim=1, codes=2).load_state_dict(buf.state_dict())


# ------------------------------------------------------------------------------------- with the trainer
def _pendulum_demos(n: int = 2, length: int = 50):
    from digail.data.trajectory import Trajectory

    rng = np.random.default_rng(0)
    out = []
    for _ in range(n):
        th = rng.uniform(-np.pi, np.pi, length + 1)
        obs = np.stack([np.cos(th), np.sin(th), rng.normal(size=length + 1)], 1).astype(np.float32)
        out.append(Trajectory(obs=obs, acts=rng.uniform(-2, 2, (length, 1)).astype(np.float32)))
    return out


def _trainer(tmp_path=None, *, method="gail", reward_fn=None, model=None, train=None, **sac):
    from digail.algos.directed_info_gail import DirectedInfoGAIL, build_trainer

    sac = {"steps_per_iteration": 100, "learning_starts": 50, "hidden": (32, 32), "policy_warmup": 0, **sac}
    cfg = TrainConfig(method=method, learner="sac", hidden=(32, 32), backend="sync", checkpoint_every=1,
                      sac=SACConfig(**sac), replay_fraction=0.0, **(train or {}))
    if model is not None:
        return DirectedInfoGAIL("Pendulum-v1", _pendulum_demos(), model, cfg, seed=0, run_dir=tmp_path,
                                progress=False, reward_fn=reward_fn)
    return build_trainer("Pendulum-v1", _pendulum_demos(), cfg, vae_model=None, seed=0, run_dir=tmp_path,
                         progress=False, reward_fn=reward_fn)


def test_resume_continues_to_the_same_weights(tmp_path):
    """Two iterations straight equal one, a checkpoint, a fresh trainer resuming from it, and one more."""
    straight = _trainer(tmp_path / "a")
    straight.train(iterations=2)
    first = _trainer(tmp_path / "b")
    first.train(iterations=1)
    resumed = _trainer(tmp_path / "b")
    resumed.load_checkpoint(tmp_path / "b" / "checkpoint.pt")
    assert resumed.learner.buffer.size == 100
    resumed.train(iterations=2)
    for part in (lambda t: t.model, lambda t: t.reward.disc):
        a, b = part(straight).state_dict(), part(resumed).state_dict()
        assert all(torch.equal(a[k], b[k]) for k in a)
    ca, cb = straight.learner.sac.critic.state_dict(), resumed.learner.sac.critic.state_dict()
    assert all(torch.equal(ca[k], cb[k]) for k in ca)
    for tr in (straight, first, resumed):
        tr.close()


def test_a_checkpoint_of_other_settings_is_one_user_error(tmp_path):
    tr = _trainer(tmp_path / "a")
    tr.train(iterations=1)
    other = _trainer(tmp_path / "b", buffer_size=500)
    with pytest.raises(UserError, match="replay buffer"):
        other.load_checkpoint(tmp_path / "a" / "checkpoint.pt")
    ppo = TrainConfig(method="gail", hidden=(32, 32), backend="sync")
    from digail.algos.directed_info_gail import build_trainer

    ppo_trainer = build_trainer("Pendulum-v1", _pendulum_demos(), ppo, vae_model=None, seed=0, run_dir=None,
                                progress=False)
    with pytest.raises(UserError, match="made with --train.learner sac"):
        ppo_trainer.load_checkpoint(tmp_path / "a" / "checkpoint.pt")
    for t in (tr, other, ppo_trainer):
        t.close()


@pytest.mark.parametrize("flag, value, phrase", [
    ("--train.sac.batch-size", "0", "--train.sac.batch-size must be at least 1"),
    ("--train.sac.gamma", "1.0", "--train.sac.gamma must be below 1"),
    ("--train.sac.init-alpha", "-1", "--train.sac.init-alpha must be positive"),
    ("--train.learner", "td3", "td3"),
    ("--demos-subsample", "0", "--demos-subsample must be at least 1"),
])
def test_bad_flags_exit_2(flag, value, phrase, capsys, tmp_path):
    from digail.cli import main

    out = tmp_path / "run"
    code = main(["train", "--method", "gail", "--demos", "digail/pendulum/expert-v0", flag, value, "--out", str(out)])
    assert code == 2
    assert phrase in capsys.readouterr().err
    assert not out.exists()


def test_sac_refuses_discrete_actions():
    from digail.algos.directed_info_gail import build_trainer
    from digail.data.trajectory import Trajectory

    demos = [Trajectory(obs=np.zeros((4, 30), np.float32), acts=np.zeros(3, np.int64))]
    cfg = TrainConfig(method="gail", learner="sac", backend="sync")
    with pytest.raises(UserError, match="continuous actions"):
        build_trainer("digail/FourRooms-v0", demos, cfg, vae_model=None, seed=0, run_dir=None, progress=False)


class ToOrigin(gym.Env):
    """A point in the plane, started uniformly in [-2, 2]^2, moved by 0.2 * action (each component in [-1, 1]),
    paid minus its distance to the origin each step, for 30 steps: a task SAC learns in about a thousand steps."""

    def __init__(self) -> None:
        self.observation_space = gym.spaces.Box(-np.inf, np.inf, (2,), np.float32)
        self.action_space = gym.spaces.Box(-1.0, 1.0, (2,), np.float32)
        self.pos = np.zeros(2, np.float32)
        self.t = 0

    def reset(self, *, seed=None, options=None):  # type: ignore[no-untyped-def]
        super().reset(seed=seed)
        self.pos = self.np_random.uniform(-2, 2, 2).astype(np.float32)
        self.t = 0
        return self.pos.copy(), {}

    def step(self, action):  # type: ignore[no-untyped-def]
        self.pos = (self.pos + 0.2 * np.clip(action, -1, 1)).astype(np.float32)
        self.t += 1
        return self.pos.copy(), -float(np.linalg.norm(self.pos)), False, self.t >= 30, {}


TOY = "DigailTest/ToOrigin-v0"
if TOY not in gym.registry:
    gym.register(TOY, entry_point=ToOrigin)


def _toy_demos():
    from digail.data.trajectory import Trajectory

    rng = np.random.default_rng(0)
    return [Trajectory(obs=rng.uniform(-2, 2, (31, 2)).astype(np.float32),
                       acts=rng.uniform(-1, 1, (30, 2)).astype(np.float32)) for _ in range(2)]


def _origin_q_model():
    """A hierarchical policy for the toy (K = 2, identity normaliser) whose frozen q prefers code 0 by
    1.5 * max(0, 4 - |x| - |y|) logits: its argmax bonus log q(0 | s) = -softplus(-1.5 max(0, 4 - |s|_1)) rises
    from -log 2 far away to about 0 at the origin, a reward for going there made of nothing but the bonus."""
    from digail.nets.vae import HierarchicalPolicy

    model = HierarchicalPolicy(2, 2, ActionSpec(False, 2), (32, 32))
    lin = [m for m in model.q.net if isinstance(m, torch.nn.Linear)]
    with torch.no_grad():
        for m in lin:
            m.weight.zero_()
            m.bias.zero_()
        for unit, (feature, sign) in enumerate([(0, 1.0), (0, -1.0), (1, 1.0), (1, -1.0)]):
            lin[0].weight[unit, feature] = sign  # |x| = relu(x) + relu(-x), the same for y
        lin[1].weight[0, :4] = -1.0
        lin[1].bias[0] = 4.0
        lin[2].weight[0, 0] = 1.5
    return model


def _toy_trainer(signal: str, sign: float = 1.0):
    from digail.algos.directed_info_gail import DirectedInfoGAIL, build_trainer

    sac = SACConfig(steps_per_iteration=500, learning_starts=300, hidden=(32, 32), policy_warmup=0, init_alpha=0.01)
    no_d = ImitationConfig(disc_every=0)
    if signal == "reward":
        cfg = TrainConfig(method="gail", learner="sac", hidden=(32, 32), backend="sync", sac=sac, imitation=no_d)
        return build_trainer(TOY, _toy_demos(), cfg, vae_model=None, seed=0, run_dir=None, progress=False,
                             reward_fn=lambda logits, batch: sign * batch["rews"])
    cfg = TrainConfig(method="digail", learner="sac", hidden=(32, 32), backend="sync", sac=sac, replay_fraction=0.0,
                      bonus_weight=sign * 10.0, closed_loop_codes="argmax", imitation=no_d)
    return DirectedInfoGAIL(TOY, _toy_demos(), _origin_q_model(), cfg, seed=0, run_dir=None, progress=False,
                            reward_fn=lambda logits, batch: 0 * logits)


def _toy_return(model) -> float:
    from digail.eval.returns import evaluate

    return float(evaluate(model, TOY, 10, deterministic=True, with_expert=False)["mean_return"])


def test_bonus_is_log_q_of_the_next_code_and_enters_the_reward():
    tr = _toy_trainer("bonus")
    tr.cfg = dataclasses.replace(tr.cfg, bonus_weight=2.0)
    tr.learner.cfg = dataclasses.replace(tr.learner.cfg, learning_starts=10_000)
    tr.iterate()
    buf = tr.learner.buffer
    n = buf.size
    l1 = np.abs(buf.next_obs[:n]).sum(1)
    expected = -np.logaddexp(0.0, -1.5 * np.maximum(0.0, 4.0 - l1))  # log q(code 0 | s'), the argmax
    np.testing.assert_allclose(buf.bonus[:n], expected, rtol=1e-5, atol=1e-6)
    assert (buf.next_codes[:n] == 0).all()
    b = buf.get(np.arange(n))
    rews, disc_rew, _ = tr.learner.rewards(b, torch.arange(n))
    torch.testing.assert_close(rews, disc_rew + 2.0 * b["bonus"])
    tr.close()


@pytest.mark.slow
@pytest.mark.parametrize("signal", ["reward", "bonus"])
def test_learns_from_the_relabelled_reward_or_from_the_bonus(signal):
    """1500 steps of SAC take the point to the origin, trained either on the env's reward passed through the
    relabelling (`reward_fn`) or on nothing but the directed-info bonus of a q that is confident there. Measured
    (seed 0): the policy before training -33; after, -4.6 on the reward and -13.1 on the bonus (whose slope
    flattens near the origin); with the sign of the reward flipped -139, the point sent away."""
    tr = _toy_trainer(signal)
    before = _toy_return(tr.model)
    tr.train(iterations=3)
    after = _toy_return(tr.model)
    tr.close()
    assert after > -20 and after > before + 10, (before, after)


def test_discriminator_hand_gradient_equals_autograd():
    """D's cross-entropy plus gradient penalty: the hand-written gradient equals autograd's (float64)."""
    from digail.algos.fast.sac_grad import disc_grads
    from digail.algos.rewards.discriminator import Discriminator, disc_loss

    torch.manual_seed(0)
    disc = Discriminator(3, 2, (8, 8)).double()
    g = torch.Generator().manual_seed(2)
    x_agent, x_expert = torch.randn(7, 5, generator=g).double(), torch.randn(6, 5, generator=g).double() + 0.5
    eps = torch.rand(6, 1, generator=g).double()
    mix = (eps * x_expert + (1 - eps) * x_agent[:6]).requires_grad_(True)
    loss, parts = disc_loss(disc, x_agent, x_expert)
    (grad_x,) = torch.autograd.grad(disc.net(mix).sum(), mix, create_graph=True)
    penalty = (grad_x.norm(dim=1) - 1.0).pow(2).mean()
    params = [*(m.weight for m in disc.net if isinstance(m, torch.nn.Linear)),
              *(m.bias for m in disc.net if isinstance(m, torch.nn.Linear))]
    expected = torch.autograd.grad(loss + 10.0 * penalty, params)
    grads, hand_parts = disc_grads(x_agent, x_expert, mix.detach(), params[:3], params[3:], 10.0)
    assert penalty.item() > 0.1
    torch.testing.assert_close(hand_parts, torch.cat([parts, penalty.detach()[None]]))
    for a, h in zip(expected, grads, strict=True):
        torch.testing.assert_close(h, a, rtol=1e-10, atol=1e-12)


def test_discriminator_scripted_step_gives_the_bits_of_the_pieces():
    """D's step as one scripted call (`disc_update`: gradient and fused Adam) against the same gradient with torch's
    own Adam step: identical weights and optimiser state after three steps."""
    runs = []
    for fused in (False, True):
        tr = _trainer(learning_starts=10_000)
        loop, d = tr.learner, tr.reward
        step = d.penalty_step
        assert step.hand
        tr.iterate()  # fills the buffer; no update yet
        if not fused:
            step._d_adam.lists = lambda: None  # type: ignore[method-assign]  # every step in pieces
        for _ in range(3):
            d._replay_step(loop.sample)
        assert (step._d_adam.lists() is not None) == fused  # after the first step: the scripted call's condition
        state = [t.clone() for st in d.optimizer.state.values() for t in st.values()]
        runs.append(([p.detach().clone() for p in d.disc.parameters()], state))
        tr.close()
    for a, b in zip(runs[0][0] + runs[0][1], runs[1][0] + runs[1][1], strict=True):
        assert torch.equal(a, b)


def test_absorbing_states_reach_d_and_the_target():
    """With absorbing states D sees [obs, flag, action]; the expert's pool gains one absorbing row per demonstration
    that terminated, and V_abs is D's reward of the absorbing state forever: softplus(logit) / (1 - gamma)."""
    from digail.algos.directed_info_gail import build_trainer
    from digail.data.trajectory import Trajectory

    demos = [Trajectory(obs=d.obs, acts=d.acts, terminated=i == 0) for i, d in enumerate(_toy_demos())]
    sac = SACConfig(steps_per_iteration=60, learning_starts=10_000, hidden=(8,), absorbing=True, gamma=0.9)
    cfg = TrainConfig(method="gail", learner="sac", hidden=(8,), backend="sync", sac=sac)
    tr = build_trainer(TOY, demos, cfg, vae_model=None, seed=0, run_dir=None, progress=False)
    loop, expert_in = tr.learner, tr.reward.inputs.expert
    assert tr.reward.disc.net[0].in_features == 2 + 1 + 2
    assert len(expert_in) == 60 + 1 and expert_in[-1, 2] == 1.0 and expert_in[:-1, 2].eq(0).all()
    tr.iterate()
    b = loop.buffer.get(np.arange(10))
    _, _, v_abs = loop.rewards(b, torch.arange(10))
    logit = tr.reward.disc.net(tr.reward.inputs.absorbing_row()).squeeze()
    torch.testing.assert_close(v_abs, torch.nn.functional.softplus(logit).detach() / 0.1)
    tr.close()


def test_cli_smoke_train_resume_evaluate(tmp_path):
    """`digail train --train.learner sac` writes a run folder whose model evaluates; `--resume` of the finished
    run changes nothing."""
    import json

    from digail.cli import main

    run = tmp_path / "run"
    argv = ["train", "--method", "gail", "--demos", "digail/pendulum/expert-v0", "--demos-episodes", "2",
            "--demos-subsample", "5", "--train.learner", "sac", "--train.iterations", "2", "--train.hidden", "16",
            "16", "--train.sac.hidden", "16", "16", "--train.sac.steps-per-iteration", "50",
            "--train.sac.learning-starts", "20", "--train.checkpoint-every", "1", "--out", str(run)]
    assert main(argv) == 0
    config = json.loads((run / "config.json").read_text())
    assert config["train"]["learner"] == "sac" and config["args"]["demos_subsample"] == 5
    assert config["fast_path"] is True  # the switch the trainer read when it was built
    header = (run / "metrics.csv").read_text().splitlines()[0]
    for key in ("losses/critic", "sac/alpha", "disc/grad_penalty", "perf/sps"):
        assert key in header
    before = torch.load(run / "checkpoint.pt", weights_only=True)
    assert before["learner"] == "sac" and before["offpolicy"]["buffer"]["size"] == 100
    assert main(["train", "--resume", str(run)]) == 0
    after = torch.load(run / "checkpoint.pt", weights_only=True)
    assert all(torch.equal(before["model"][k], after["model"][k]) for k in before["model"])
    assert main(["evaluate", str(run), "--episodes", "2"]) == 0
    assert json.loads((run / "eval.json").read_text())["episodes"] == 2


@pytest.mark.parametrize("init_from_vae", [True, False])
def test_a_fresh_policy_keeps_the_vaes_q(init_from_vae):
    """`--train.no-init-from-vae` (the few-demonstration presets) redraws pi's weights and keeps the VAE's q,
    prior and normaliser, so the codes and the bonus are still the VAE's."""
    import copy

    from digail.algos.directed_info_gail import build_trainer
    from digail.nets.vae import HierarchicalPolicy

    torch.manual_seed(3)
    vae = HierarchicalPolicy(3, 2, ActionSpec(False, 1), (32, 32))
    with torch.no_grad():
        vae.pi.log_std.fill_(-0.5)
    before = copy.deepcopy(vae)
    cfg = TrainConfig(method="digail", learner="sac", hidden=(32, 32), backend="sync", replay_fraction=0.0,
                      init_from_vae=init_from_vae, sac=SACConfig(hidden=(32, 32)))
    trainer = build_trainer("Pendulum-v1", _pendulum_demos(), cfg, vae_model=vae, seed=0, run_dir=None,
                            progress=False)
    try:
        for part in ("q", "prior", "normalizer"):
            for a, b in zip(getattr(before, part).state_dict().values(),
                            getattr(trainer.model, part).state_dict().values(), strict=True):
                assert torch.equal(a, b), part
        same_pi = all(torch.equal(a, b) for a, b in zip(before.pi.state_dict().values(),
                                                       trainer.model.pi.state_dict().values(), strict=True))
        assert same_pi == init_from_vae
    finally:
        trainer.close()


@pytest.mark.parametrize("learner", ["sac", "ppo"])
@pytest.mark.parametrize("zero", [True, False])
def test_zero_code_weights_start_every_code_alike(learner, zero):
    """`--train.zero-code-weights` makes the fresh policy, V and both critics (and their targets) give the same
    outputs under every code at the start, and only their code inputs' weights differ from the default start."""
    import copy

    from digail.algos.directed_info_gail import build_trainer
    from digail.nets.vae import HierarchicalPolicy

    torch.manual_seed(3)
    vae = HierarchicalPolicy(3, 3, ActionSpec(False, 1), (32, 32))

    def built(zero_code_weights: bool):
        cfg = TrainConfig(method="digail", learner=learner, hidden=(32, 32), backend="sync", replay_fraction=0.0,
                          init_from_vae=False, zero_code_weights=zero_code_weights, sac=SACConfig(hidden=(32, 32)))
        return build_trainer("Pendulum-v1", _pendulum_demos(), cfg, vae_model=copy.deepcopy(vae), seed=0,
                             run_dir=None, progress=False)

    trainer, default = built(zero), built(False)
    try:
        obs, act = torch.randn(5, 3), torch.randn(5, 1)
        codes = [torch.eye(3)[c].expand(5, 3) for c in range(3)]
        outs = {"pi": [trainer.model.pi.mode(obs, c) for c in codes],
                **({"V": [trainer.learner.value(obs, c) for c in codes]} if learner == "ppo" else {})}
        if learner == "sac":
            learner_ = trainer.learner.sac
            for name, net in (("Q", learner_.critic), ("Q target", learner_.critic_target)):
                outs[name] = [net(torch.cat([obs, c, act], -1)) for c in codes]
        for name, per_code in outs.items():
            alike = all(torch.equal(per_code[0], o) for o in per_code[1:])
            assert alike == zero, name
        # the same draw as the default apart from the code columns (weights and biases listed in one order)
        nets = [(trainer.model.pi, default.model.pi)]
        if learner == "ppo":
            nets.append((trainer.learner.value, default.learner.value))
        for net, ref in nets:
            first_w = [k for k in net.state_dict() if k.endswith("weight")][0]
            for k, v in net.state_dict().items():
                if k == first_w:
                    assert torch.equal(v[:, :-3], ref.state_dict()[k][:, :-3])
                else:
                    assert torch.equal(v, ref.state_dict()[k]), k
    finally:
        trainer.close()
        default.close()
