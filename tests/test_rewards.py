"""Imitation rewards (`--train.imitation.*`, `digail.algos.rewards`): the positive-unlabeled loss, Sinkhorn's plan,
the optimal-transport reward and its sub-task mask, the Q-filtered BC term, the registry and each reward's state."""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
import pytest
import torch

from digail.algos.aux_losses import qfiltered_bc_loss
from digail.algos.directed_info_gail import build_trainer
from digail.algos.expert_data import ExpertData, relabelled_goals
from digail.algos.rewards import REWARDS, DiscReward, EnvReward, OTReward, WeightedSum, pu_loss, sinkhorn_plan
from digail.algos.rewards.ot import ot_step_rewards, window_mask
from digail.config import PPOConfig, SACConfig, TrainConfig
from digail.errors import UserError
from digail.imitation_config import REWARD_KINDS, ImitationConfig
from digail.nets.policy import ActionSpec
from digail.nets.vae import HierarchicalPolicy

SMALL = TrainConfig(iterations=2, value_warmup=0,
                    ppo=PPOConfig(num_envs=4, batch_size=128, epochs=2, minibatch_size=64))


def _sp(x: float) -> float:
    return math.log1p(math.exp(x))


def test_pu_loss_by_hand():
    """eta E_E[-log D] + max(0, E_A[-log(1 - D)] - eta E_E[-log(1 - D)]), with softplus written out."""
    got = pu_loss(torch.tensor([0.0, 1.0]), torch.tensor([2.0]), 0.3)
    neg = 0.5 * (_sp(0.0) + _sp(1.0)) - 0.3 * _sp(2.0)
    assert float(got) == pytest.approx(0.3 * _sp(-2.0) + neg, abs=1e-5)
    # the agent's negative risk below the expert-like share: clamped at 0, only the positive risk is left
    got = pu_loss(torch.tensor([-5.0]), torch.tensor([-1.0]), 0.5)
    assert _sp(-5.0) - 0.5 * _sp(-1.0) < 0
    assert float(got) == pytest.approx(0.5 * _sp(1.0), abs=1e-5)


def test_sinkhorn_plan_has_uniform_marginals_on_the_valid_steps():
    gen = torch.Generator().manual_seed(0)
    cost = torch.rand(3, 6, 9, generator=gen) * 2
    a_mask = torch.ones(3, 6, dtype=torch.bool)
    a_mask[1, 4:] = False
    b_mask = torch.ones(3, 9, dtype=torch.bool)
    b_mask[2, :3] = False
    plan = sinkhorn_plan(cost, a_mask, b_mask, epsilon=0.1, iterations=200)
    rows, cols = plan.sum(-1), plan.sum(-2)
    for i in range(3):
        na, nb = int(a_mask[i].sum()), int(b_mask[i].sum())
        torch.testing.assert_close(rows[i][a_mask[i]], torch.full((na,), 1 / na), atol=1e-4, rtol=0)
        torch.testing.assert_close(cols[i][b_mask[i]], torch.full((nb,), 1 / nb), atol=1e-5, rtol=0)
    assert float(plan[1, 4:].abs().sum()) == 0.0 and float(plan[2, :, :3].abs().sum()) == 0.0
    # a small epsilon concentrates the plan on the cheap pairs: a diagonal cost gives the identity / n
    eye_plan = sinkhorn_plan(1 - torch.eye(5), torch.ones(5, dtype=torch.bool), torch.ones(5, dtype=torch.bool),
                             epsilon=0.02, iterations=100)
    torch.testing.assert_close(eye_plan, torch.eye(5) / 5, atol=1e-4, rtol=0)


def _demos(gen: torch.Generator, m: int = 3, length: int = 20, feats: int = 6) -> torch.Tensor:
    """Smooth random paths in feature space (M, L, F)."""
    steps = torch.randn(m, length, feats, generator=gen) * 0.3
    return steps.cumsum(1) + torch.randn(m, 1, feats, generator=gen)


def test_ot_reward_ranks_an_expert_like_episode_above_a_random_one():
    gen = torch.Generator().manual_seed(1)
    demos = _demos(gen)
    length = demos.shape[1]
    near = demos[1] + 0.05 * torch.randn(length, demos.shape[2], generator=gen)
    far = torch.randn(length, demos.shape[2], generator=gen) * 2
    agent = torch.stack([near, far])
    mask = torch.ones(2, length, dtype=torch.bool)
    demo_mask = torch.ones(2, 3, length, dtype=torch.bool)
    rews, total = ot_step_rewards(agent, mask, demos, demo_mask, epsilon=0.05, iterations=50, top_k=1, scale=1.0)
    assert float(rews[0].mean()) > float(rews[1].mean()) + 0.3
    assert int(total[0].argmin()) == 1  # the closest demonstration is the one the episode copies
    assert float(rews.max()) <= 0.0 and float(rews.min()) >= -2.0


def test_subtask_ot_matches_a_step_to_demonstration_steps_of_its_code():
    """The demonstration's halves look different (features f0 then f1) and carry codes 0 then 1. An agent that
    copies the features with the same codes pays nothing; with its codes swapped each step pays either the code
    penalty or the features' distance, about 1. Without codes the two are the same; with equidistant features the
    plan puts each step's mass on demonstration steps of its own code."""
    demo = torch.zeros(1, 10, 3)
    demo[0, :5, 0] = 1.0
    demo[0, 5:, 1] = 1.0
    demo_codes = torch.tensor([[0] * 5 + [1] * 5])
    agent = demo.clone()
    mask, demo_mask = torch.ones(1, 10, dtype=torch.bool), torch.ones(1, 1, 10, dtype=torch.bool)
    kw = dict(epsilon=0.05, iterations=100, top_k=1, scale=1.0, demo_codes=demo_codes, code_penalty=1.0)
    same, _ = ot_step_rewards(agent, mask, demo, demo_mask, agent_codes=demo_codes.clone(), **kw)
    swapped, _ = ot_step_rewards(agent, mask, demo, demo_mask, agent_codes=1 - demo_codes, **kw)
    assert float(same.mean()) > -0.05 and float(swapped.mean()) < -0.9
    plain, _ = ot_step_rewards(agent, mask, demo, demo_mask, **{**kw, "code_penalty": 0.0},
                               agent_codes=1 - demo_codes)
    assert float(plain.mean()) > -0.05
    from digail.algos.rewards.ot import cosine_cost

    middle = torch.ones(1, 10, 3) * torch.tensor([1.0, 1.0, 0.0])  # as far from f0 as from f1
    cost = cosine_cost(middle, demo)[0] + 1.0 * (demo_codes[0][:, None] != demo_codes[0][None, :]).float()
    plan = sinkhorn_plan(cost, mask[0], demo_mask[0, 0], 0.05, 100)
    assert float(plan[:5, :5].sum() + plan[5:, 5:].sum()) > 0.99


def test_euclidean_cost_grades_how_far_a_step_is_where_the_cosine_does_not():
    """Two agent episodes copy a demonstration's direction in feature space at 1.5x and 3x its length: the cosine
    finds both perfect, the Euclidean cost (root-mean-square difference per feature) pays in proportion to how far
    each lies, which is what tells a block 5 cm from the goal from one 20 cm away."""
    from digail.algos.rewards.ot import euclidean_cost

    gen = torch.Generator().manual_seed(2)
    demos = _demos(gen, m=1, length=15, feats=4)
    agent = torch.stack([demos[0] * 1.5, demos[0] * 3.0])
    mask = torch.ones(2, 15, dtype=torch.bool)
    demo_mask = torch.ones(2, 1, 15, dtype=torch.bool)
    kw = dict(epsilon=0.01, iterations=100, top_k=1, scale=1.0)
    cos, _ = ot_step_rewards(agent, mask, demos, demo_mask, **kw)
    euc, _ = ot_step_rewards(agent, mask, demos, demo_mask, metric="euclidean", **kw)
    assert float(cos.mean()) > -0.02 and abs(float(cos[0].mean() - cos[1].mean())) < 0.02
    assert float(euc[1].mean()) < 2 * float(euc[0].mean()) + 0.05 < 0.0
    x, y = torch.tensor([[0.0, 0.0, 0.0, 0.0]]), torch.tensor([[1.0, 1.0, 1.0, 1.0], [2.0, 0.0, 0.0, 0.0]])
    torch.testing.assert_close(euclidean_cost(x, y), torch.tensor([[1.0, 1.0]]))
    with pytest.raises(UserError, match="--train.imitation.ot-cost must be one of cosine, euclidean"):
        ImitationConfig(ot_cost="l1")  # type: ignore[arg-type]


def test_window_mask_matches_a_piece_to_the_same_stretch_of_episode_time():
    lengths = torch.tensor([50, 30])
    mask = window_mask(lengths, starts=torch.tensor([38, 0, 0]), sizes=torch.tensor([12, 12, 40]),
                       whole=torch.tensor([False, False, True]), longest=50)
    assert mask[0, 0].nonzero().squeeze(-1).tolist() == list(range(38, 50))
    assert mask[0, 1].nonzero().squeeze(-1).tolist() == list(range(18, 30))  # moved back into the shorter one
    assert mask[1, 0].nonzero().squeeze(-1).tolist() == list(range(12))
    assert int(mask[2, 0].sum()) == 50 and int(mask[2, 1].sum()) == 30  # a whole episode: all of each


def test_qfilter_keeps_bc_only_where_the_expert_action_is_valued_higher():
    torch.manual_seed(0)
    pi = HierarchicalPolicy(2, 1, ActionSpec(False, 1)).pi
    obs = torch.linspace(-1, 1, 8)[:, None].repeat(1, 2)
    acts = torch.linspace(-1, 1, 8)[:, None]
    expert = ExpertData(obs_n=obs, acts=acts, disc_in=obs, codes=torch.zeros(8, dtype=torch.long),
                        replay_codes=np.zeros((1, 8), np.int64))
    with torch.no_grad():
        mean = pi.mode(obs, torch.ones(8, 1))

    def critic(x):  # Q(s, c, a) = a: the larger action is worth more
        return x[:, -1:].T.repeat(2, 1)

    gen = torch.Generator().manual_seed(3)
    loss, kept = qfiltered_bc_loss(pi, expert, torch.eye(1), 64, gen, critic, lambda a: a)
    idx = torch.randint(8, (64,), generator=torch.Generator().manual_seed(3))
    keep = (acts[idx, 0] > mean[idx, 0]).float()
    assert 0 < float(keep.mean()) < 1  # the test draws both kinds of step
    assert float(kept) == pytest.approx(float(keep.mean()))
    expected = ((mean[idx] - acts[idx]).pow(2).sum(-1) * keep).mean()
    assert float(loss.detach()) == pytest.approx(float(expected), rel=1e-5)
    loss.backward()  # the gradient reaches pi only through the kept steps
    assert pi.net[0].weight.grad is not None


def test_registry_has_a_row_for_every_kind_and_each_builds(circle_demos):
    assert set(REWARDS) == set(REWARD_KINDS)
    for kind in REWARD_KINDS:
        cfg = replace(SMALL, imitation=ImitationConfig(reward=kind))
        trainer = build_trainer("digail/CircleWorld-v0", circle_demos, cfg, vae_model=_vae(circle_demos), seed=0,
                                run_dir=None, progress=False)
        try:
            expected = {"bce": DiscReward, "pu": DiscReward, "env": EnvReward}.get(kind, OTReward)
            assert type(trainer.reward) is expected
            out = trainer.iterate()
            assert ("disc/loss" in out) == (expected is DiscReward)
            assert math.isfinite(out["rollout/disc_reward"])
            if kind.startswith("ot"):
                assert out["rollout/disc_reward"] <= 0 and math.isfinite(out["reward/ot_episode"])
        finally:
            trainer.close()


def test_bad_imitation_settings_are_one_sentence():
    with pytest.raises(UserError, match="--train.imitation.reward must be one of"):
        ImitationConfig(reward="wasserstein")  # type: ignore[arg-type]
    with pytest.raises(UserError, match="--train.imitation.pu-prior must be between 0 and 1"):
        ImitationConfig(pu_prior=1.0)
    with pytest.raises(UserError, match="--train.imitation.ot-top-k must be at least 1"):
        ImitationConfig(ot_top_k=0)


def test_relabelled_goals_are_where_the_object_is_later_in_the_same_demonstration():
    """Columns 0:2 are the goal, 2:4 the object (its x is the step number, its y the demonstration), 4 a bystander:
    each copy's goal is the object at a strictly later step of its own demonstration, all else as recorded."""
    from digail.data.trajectory import Trajectory

    demos = []
    for d, steps in enumerate((6, 9)):
        obs = np.zeros((steps + 1, 5), np.float32)
        obs[:, 0:2] = -1.0
        obs[:, 2] = np.arange(steps + 1)
        obs[:, 3] = d
        obs[:, 4] = 7.0
        demos.append(Trajectory(obs=obs, acts=np.arange(steps, dtype=np.float32)[:, None] + 100 * d))
    obs, acts = relabelled_goals(demos, slice(0, 2), slice(2, 4), 3, np.random.default_rng(0))
    assert obs.shape == (3 * 15, 5) and acts.shape == (3 * 15, 1)
    step = acts[:, 0] % 100  # the step each row copies (its action says which)
    demo = acts[:, 0] // 100
    np.testing.assert_array_equal(obs[:, 2], step)
    np.testing.assert_array_equal(obs[:, 1], demo)  # the goal's y: the same demonstration's object
    assert np.all(obs[:, 0] > step) and np.all(obs[:, 0] <= np.where(demo == 0, 6, 9))
    assert np.all(obs[:, 4] == 7.0)
    assert len(np.unique(obs[:, 0])) > 5  # the later steps are drawn, not always the last


def test_goal_relabelling_is_refused_where_it_cannot_apply(circle_demos):
    with pytest.raises(UserError, match="--train.imitation.relabel-goals must be 0 with an optimal-transport"):
        ImitationConfig(reward="ot", relabel_goals=2)
    with pytest.raises(UserError, match="--train.imitation.relabel-goals must be a whole number"):
        ImitationConfig(relabel_goals=-1)
    cfg = replace(SMALL, imitation=ImitationConfig(relabel_goals=2))
    with pytest.raises(UserError, match="needs a goal-conditioned env.*set it to 0"):
        build_trainer("digail/CircleWorld-v0", circle_demos, cfg, vae_model=_vae(circle_demos), seed=0,
                      run_dir=None, progress=False)


def _vae(demos, codes=2):
    torch.manual_seed(0)
    model = HierarchicalPolicy(2, codes, ActionSpec(False, 2))
    model.normalizer.fit(np.concatenate([t.obs for t in demos]))
    return model


@pytest.mark.parametrize("imitation", [ImitationConfig(reward="pu", disc_noise=0.1, spectral_norm=True,
                                                       disc_dropout=0.1, disc_weight_decay=1e-3),
                                       ImitationConfig(reward="ot-subtask", ot_time_weight=0.5)])
def test_ppo_reward_state_round_trips(tmp_path, circle_demos, imitation):
    """A checkpoint restores the reward's state: a fresh trainer and the original, both loaded from it, run the
    same next iteration."""
    cfg = replace(SMALL, imitation=imitation, checkpoint_every=1)

    def make():
        return build_trainer("digail/CircleWorld-v0", circle_demos, cfg, vae_model=_vae(circle_demos), seed=0,
                             run_dir=None, progress=False)

    a, b = make(), make()
    try:
        a.iterate()
        a.save_checkpoint(tmp_path / "checkpoint.pt")
        a.iterate()  # moves on: the load must bring it back
        for t in (a, b):
            t.load_checkpoint(tmp_path / "checkpoint.pt")
        out_a, out_b = a.iterate(), b.iterate()
        for key in ("rollout/disc_reward", "losses/policy"):
            assert out_a[key] == out_b[key]
        if isinstance(a.reward, DiscReward):
            assert isinstance(b.reward, DiscReward)
            for p, q in zip(a.reward.disc.parameters(), b.reward.disc.parameters(), strict=True):
                assert torch.equal(p, q)
    finally:
        a.close()
        b.close()


def _pendulum_demos(n: int = 2, length: int = 40):
    from digail.data.trajectory import Trajectory

    rng = np.random.default_rng(0)
    out = []
    for _ in range(n):
        th = rng.uniform(-np.pi, np.pi, length + 1)
        obs = np.stack([np.cos(th), np.sin(th), rng.normal(size=length + 1)], 1).astype(np.float32)
        out.append(Trajectory(obs=obs, acts=rng.uniform(-2, 2, (length, 1)).astype(np.float32)))
    return out


def _pendulum_trainer(imitation: ImitationConfig, bc_weight: float = 0.0):
    sac = SACConfig(steps_per_iteration=100, learning_starts=50, hidden=(32, 32), policy_warmup=0, batch_size=32)
    cfg = TrainConfig(method="gail", learner="sac", hidden=(32, 32), backend="sync", sac=sac, replay_fraction=0.0,
                      imitation=imitation, bc_weight=bc_weight)
    return build_trainer("Pendulum-v1", _pendulum_demos(n=2, length=40), cfg, vae_model=None, seed=0, run_dir=None,
                         progress=False)


def test_sac_ot_reward_scores_episodes_and_round_trips():
    """Off-policy: each finished episode's steps get their transport reward in the buffer's positions; the
    episodes under way travel in the checkpoint, and a restored reward scores them as the original does."""
    a = _pendulum_trainer(ImitationConfig(reward="ot"))
    b = _pendulum_trainer(ImitationConfig(reward="ot"))
    try:
        a.iterate()
        assert isinstance(a.reward, OTReward) and isinstance(b.reward, OTReward)
        replay = a.reward._replay
        assert replay is not None and len(replay) == 100
        # Pendulum's episodes last 200 steps: after 100 none has ended, every position still reads 0
        assert np.all(replay == 0)
        b.load_state_dict(a.state_dict())
        for t in (a, b):
            t.rollout_state = None  # both restart their envs, cutting the episode here (as a checkpoint's restart)
            t.iterate()
        assert np.all(a.reward._replay[:100] < 0) and np.all(a.reward._replay[100:] == 0)
        np.testing.assert_array_equal(a.reward._replay, b.reward._replay)
    finally:
        a.close()
        b.close()


def test_sac_qfilter_logs_the_share_of_bc_kept():
    t = _pendulum_trainer(ImitationConfig(bc_schedule="qfilter"), bc_weight=1.0)
    try:
        out = t.iterate()
        assert 0.0 <= out["losses/bc_kept"] <= 1.0
        assert out["losses/bc_weight"] == 1.0
    finally:
        t.close()


def test_qfilter_with_ppo_is_refused(circle_demos):
    cfg = replace(SMALL, imitation=ImitationConfig(bc_schedule="qfilter"))
    with pytest.raises(UserError, match="qfilter needs a critic"):
        build_trainer("digail/CircleWorld-v0", circle_demos, cfg, vae_model=_vae(circle_demos), seed=0,
                      run_dir=None, progress=False)


def test_anneal_decays_the_bc_weight_to_zero(circle_demos):
    cfg = replace(SMALL, iterations=4, bc_weight=2.0, imitation=ImitationConfig(bc_schedule="anneal"))
    trainer = build_trainer("digail/CircleWorld-v0", circle_demos, cfg, vae_model=_vae(circle_demos), seed=0,
                            run_dir=None, progress=False)
    try:
        trainer.learner.total_iterations = 4
        weights = []
        for _ in range(4):
            weights.append(trainer.iterate()["losses/bc_weight"])
        assert weights == pytest.approx([2.0, 1.5, 1.0, 0.5])
    finally:
        trainer.close()


@pytest.mark.parametrize("imitation", [ImitationConfig(reward="pu", disc_noise=0.1, spectral_norm=True,
                                                       disc_dropout=0.1),
                                       ImitationConfig(reward="ot", ot_time_weight=0.5),
                                       ImitationConfig(reward="ot", ot_cost="euclidean")])
def test_sac_runs_each_reward_with_plain_gail(imitation):
    """Off-policy, one code: the regularised PU step updates D; the transport reward trains with no D at all."""
    t = _pendulum_trainer(imitation)
    try:
        disc = t.reward.disc if isinstance(t.reward, DiscReward) else None
        before = None if disc is None else [p.detach().clone() for p in disc.parameters()]
        out = t.iterate()
        assert math.isfinite(out["losses/critic"])
        if disc is None:
            assert "disc/loss" not in out  # no D, no D scalars
        else:
            assert math.isfinite(out["disc/loss"]) and 0.0 <= out["disc/acc_expert"] <= 1.0
            assert any(not torch.equal(a, b) for a, b in zip(before, disc.parameters(), strict=True))
    finally:
        t.close()


def _trainer_for(learner: str, circle_demos, imitation: ImitationConfig):
    """A small trainer with `imitation`: PPO on Circle-World, or SAC on Pendulum."""
    if learner == "ppo":
        return build_trainer("digail/CircleWorld-v0", circle_demos, replace(SMALL, imitation=imitation),
                             vae_model=_vae(circle_demos), seed=0, run_dir=None, progress=False)
    return _pendulum_trainer(imitation)


@pytest.mark.parametrize("learner", ["ppo", "sac"])
def test_a_state_only_d_ignores_the_action(circle_demos, learner):
    """`disc_actions=False`: D's input is the state (or its view) alone, on the agent's rows and the expert's, so two
    agent steps that differ only in their action get the same logit; D still trains on both learners."""
    imitation = ImitationConfig(disc_actions=False)
    t = _trainer_for(learner, circle_demos, imitation)
    try:
        d = t.reward
        assert isinstance(d, DiscReward)
        obs_dim = t.expert.obs_n.shape[1]
        assert d.inputs.expert.shape[1] == obs_dim
        assert d.disc.net[0].in_features == obs_dim
        obs = t.expert.obs_n[:5]
        acts = torch.randn(5, t.expert.disc_in.shape[1] - obs_dim)
        torch.testing.assert_close(d.logits(d.inputs.rows(obs, acts)), d.logits(d.inputs.rows(obs, -acts)))
        before = [p.detach().clone() for p in d.disc.parameters()]
        out = t.iterate()
        assert math.isfinite(out["disc/loss"])
        assert any(not torch.equal(a, b) for a, b in zip(before, d.disc.parameters(), strict=True))
    finally:
        t.close()


@pytest.mark.parametrize("learner", ["ppo", "sac"])
def test_a_weighted_sum_pays_each_term_times_its_weight(circle_demos, learner):
    """`--train.imitation.terms env:0.25` beside D: the sum pays D's reward plus a quarter of the env's, on a rollout
    and on replayed transitions, and D still learns (its scalars come through the sum)."""
    imitation = ImitationConfig(terms=("env:0.25",))
    t = _trainer_for(learner, circle_demos, imitation)
    try:
        s = t.reward
        assert isinstance(s, WeightedSum)
        (w_d, d), (w_env, env) = s.terms
        assert (w_d, w_env) == (1.0, 0.25) and isinstance(d, DiscReward) and isinstance(env, EnvReward)
        out = t.iterate()
        assert math.isfinite(out["disc/loss"])
        from digail.algos.rewards import Steps

        if learner == "ppo":
            batch = t.learner.collect()
            T, N = batch["logp"].shape
            flat_acts = batch["acts"].reshape(T * N, *batch["acts"].shape[2:])
            steps = Steps(obs=batch["obs"].reshape(T * N, -1), acts=t.act_input(flat_acts), batch=batch)
        else:
            idx = torch.arange(16)
            b = t.learner.buffer.get(idx)
            steps = Steps(obs=b["obs"], acts=b["acts"], batch=b, idx=idx)
        with torch.no_grad():
            total, from_d = s.rewards(steps), d.rewards(steps)
        assert not torch.allclose(total, from_d)  # the env's term counts
        torch.testing.assert_close(total, from_d + 0.25 * steps.batch["rews"].float())
    finally:
        t.close()


def test_terms_are_checked_when_set():
    assert ImitationConfig(terms=("env:0.5",)).term_weights == (("env", 0.5),)
    with pytest.raises(UserError, match="--train.imitation.terms must be name:weight"):
        ImitationConfig(terms=("env",))
    with pytest.raises(UserError, match="--train.imitation.terms must be name:weight with a finite number"):
        ImitationConfig(terms=("env:lots",))
    with pytest.raises(UserError, match="--train.imitation.terms must be a reward named once"):
        ImitationConfig(terms=("bce:1",))
    with pytest.raises(UserError, match="at most one D-based"):
        ImitationConfig(terms=("pu:1",))
