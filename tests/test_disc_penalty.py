"""The gradient penalty on D (`--train.imitation.disc-grad-penalty`, DAC's) and its default per learner."""

from __future__ import annotations

import pytest
import torch

from digail.algos.rewards.discriminator import Discriminator, discriminator_update, gradient_penalty
from digail.config import TrainConfig
from digail.errors import UserError
from digail.imitation_config import ImitationConfig


def test_the_penalty_is_zero_for_a_unit_slope_and_grows_with_the_slope() -> None:
    disc = Discriminator(2, 1, hidden=())
    lin = disc.net[0] if isinstance(disc.net, torch.nn.Sequential) else disc.net
    gen = torch.Generator().manual_seed(0)
    x_a, x_e = torch.randn(64, 3, generator=gen), torch.randn(64, 3, generator=gen)
    with torch.no_grad():
        lin.weight.copy_(torch.tensor([[0.6, 0.8, 0.0]]))  # |grad| = 1 everywhere
    assert gradient_penalty(disc, x_a, x_e, gen).item() == pytest.approx(0.0, abs=1e-10)
    with torch.no_grad():
        lin.weight.mul_(3.0)  # |grad| = 3: (3 - 1)^2
    assert gradient_penalty(disc, x_a, x_e, gen).item() == pytest.approx(4.0, rel=1e-5)


def test_with_four_expert_points_the_penalty_keeps_ds_logits_from_a_cliff() -> None:
    """Four expert rows against a cloud of agent rows: without the penalty D learns them by heart (a large logit
    gap); with it the gap stays small, so the agent's reward still grades how close it comes."""
    gen = torch.Generator().manual_seed(0)
    x_expert = torch.randn(4, 6, generator=gen)
    x_agent = torch.randn(512, 6, generator=gen) * 1.5

    def gap(weight: float) -> float:
        torch.manual_seed(0)
        disc = Discriminator(5, 1)
        opt = torch.optim.Adam(disc.parameters(), lr=1e-3)
        g = torch.Generator().manual_seed(1)
        for _ in range(30):
            discriminator_update(disc, opt, x_agent, x_expert, updates=1, minibatch_size=128, gen=g,
                                 grad_penalty=weight)
        with torch.no_grad():
            return float(disc.net(x_expert).mean() - disc.net(x_agent).mean())

    free, held = gap(0.0), gap(10.0)
    assert free > 2 * held and free > 4.0, (free, held)


def test_a_negative_penalty_is_refused() -> None:
    with pytest.raises(UserError, match="--train.imitation.disc-grad-penalty"):
        ImitationConfig(disc_grad_penalty=-1.0)


def test_one_penalty_setting_whose_default_depends_on_the_learner() -> None:
    """None: none with PPO, DAC's 10 with SAC; a value set applies to either learner."""
    assert TrainConfig(learner="ppo").effective_disc_grad_penalty == 0.0
    assert TrainConfig(learner="sac").effective_disc_grad_penalty == 10.0
    for learner in ("ppo", "sac"):
        cfg = TrainConfig(learner=learner, imitation=ImitationConfig(disc_grad_penalty=2.5))  # type: ignore[arg-type]
        assert cfg.effective_disc_grad_penalty == 2.5
