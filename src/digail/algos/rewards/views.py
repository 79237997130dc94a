"""What a reward sees of the agent's and the expert's steps: D's view of the observation (`--train.imitation.disc-obs`),
shared by every reward that compares steps (D's inputs, the optimal-transport features), and D's input rows (the
view, the absorbing flag, the action) for the agent, the demonstrations and DAC's absorbing state.
"""

from __future__ import annotations

import importlib
from collections.abc import Callable
from typing import TYPE_CHECKING

import numpy as np
import torch
from torch import nn

from digail.algos.expert_data import disc_rows, relabelled_goals
from digail.envs.registry import env_spec
from digail.errors import UserError
from digail.nets.normalizer import ObsNormalizer

if TYPE_CHECKING:
    from digail.algos.rewards.base import RewardHost


class ObsView(nn.Module):
    """The part of a normalised observation D sees: `fn` of the raw observation (the normaliser undone), normalised
    again on the demonstrations' values of it.

    Args:
        fn: raw observations (n, D) -> D's features (n, F), torch in and out (an env's `relative_view`).
        normalizer: the policy's fixed observation normaliser, whose statistics it undoes.
        demo_obs: (M, D) raw demonstration observations, which set the features' statistics.
    """

    mean: torch.Tensor
    std: torch.Tensor

    def __init__(self, fn: Callable[[torch.Tensor], torch.Tensor], normalizer: ObsNormalizer,
                 demo_obs: np.ndarray) -> None:
        super().__init__()
        self.fn = fn
        self.register_buffer("mean", normalizer.mean.detach().clone().cpu())
        self.register_buffer("std", normalizer.std.detach().clone().cpu())
        with torch.no_grad():
            feats = _checked_features(fn, torch.as_tensor(np.asarray(demo_obs, np.float32)))
        self.out = ObsNormalizer(feats.shape[1]).fit(feats.numpy())
        self.dim = int(feats.shape[1])
        """F, the features D sees in place of the observation"""

    def forward(self, obs_n: torch.Tensor) -> torch.Tensor:
        name = getattr(self.fn, "__qualname__", repr(self.fn))
        try:
            feats = self.fn(obs_n * self.std + self.mean)
        except (Exception, SystemExit) as exc:  # noqa: BLE001  (the user's function: whatever it raises, one answer)
            raise UserError(f"D's view {name} fails on observations met during training ({type(exc).__name__}: "
                            f"{str(exc).strip()[:120]}); it must map every observation the env gives.") from None
        # the agent's observations are not the ones checked at the start: a view that changes width would be
        # broadcast against the demonstrations' statistics, and NaN would reach D's loss as a "non-finite loss"
        if not (isinstance(feats, torch.Tensor) and feats.shape == (obs_n.shape[0], self.dim)):
            got = tuple(feats.shape) if isinstance(feats, torch.Tensor) else type(feats).__name__
            raise UserError(f"D's view {name} returned {got} for {tuple(obs_n.shape)} observations during training "
                            f"after {self.dim} features per step on the demonstrations at the start; it must give the "
                            "same number of features for every observation.")
        if not torch.isfinite(feats).all():
            raise UserError(f"D's view {name} gives NaN or infinite features on observations met during training "
                            "(the demonstrations' were finite at the start); make it finite for every observation the "
                            "env can give.")
        return self.out(feats.float())


def _checked_features(fn: Callable[[torch.Tensor], torch.Tensor], obs: torch.Tensor) -> torch.Tensor:
    """`fn(obs)`, refused in one sentence unless it is a finite float tensor with a row per observation."""
    name = getattr(fn, "__qualname__", repr(fn))
    try:
        feats = fn(obs)
    except (Exception, SystemExit) as exc:  # noqa: BLE001  (the user's function: whatever it raises, one answer)
        raise UserError(f"D's view {name} fails on the demonstrations' observations ({type(exc).__name__}: "
                        f"{str(exc).strip()[:120]}); it must map a float tensor (n, D) to features (n, F).") from None
    if not (isinstance(feats, torch.Tensor) and feats.dim() == 2 and feats.shape[0] == obs.shape[0]
            and feats.shape[1] >= 1 and feats.is_floating_point()):
        got = tuple(feats.shape) if isinstance(feats, torch.Tensor) else type(feats).__name__
        raise UserError(f"D's view {name} returned {got} for {tuple(obs.shape)} observations; it must return a "
                        "float tensor with one row of features per observation, (n, F).")
    if not torch.isfinite(feats).all():
        raise UserError(f"D's view {name} gives NaN or infinite features on the demonstrations; make it finite.")
    return feats.float()


SHIPPED_VIEWS = frozenset({"digail.envs.fetch:placing_view", "digail.envs.fetch:distances_view",
                           "digail.envs.fetch:log_distances_view"})
"""`module:function` views that digail itself ships beside the envs' relative views: a run folder that records one
names no code of the user's, so resuming it needs no `--train.imitation.disc-obs`"""


def obs_view(env_id: str, kind: str, normalizer: ObsNormalizer, demo_obs: np.ndarray) -> ObsView | None:
    """D's view of the observation for `--train.imitation.disc-obs kind`: None for `all`, the env's relative view for
    `relative`, or the user's function for `module:function`."""
    if kind == "all":
        return None
    if kind == "relative":
        from digail.envs.registry import env_spec

        spec = env_spec(env_id)
        if spec is None or spec.relative_view is None:
            raise UserError(f"{env_id} has no relative view of its observation for D; use --train.imitation.disc-obs "
                            "all, or write one and pass it as --train.imitation.disc-obs module:function.")
        module, _, name = spec.relative_view.partition(":")
        return ObsView(getattr(importlib.import_module(module), name), normalizer, demo_obs)
    from digail.user_envs import import_function

    return ObsView(import_function(kind, "--train.imitation.disc-obs"), normalizer, demo_obs)


class RewardInputs:
    """The steps as the rewards of one trainer see them: D's view of the observation (None: all of it) and D's input
    rows [the view, (the absorbing flag,) the action], the action left out where D judges states alone
    (`--train.imitation.disc-actions` off), the flag only with absorbing states (DAC, the learner's choice).

    Args:
        host: the trainer (its env, demonstrations, normaliser, expert data and settings).
    """

    def __init__(self, host: RewardHost) -> None:
        cfg, model = host.cfg.imitation, host.model
        self.host = host
        self.view = obs_view(host.env_id, cfg.disc_obs, model.normalizer,
                             np.concatenate([np.asarray(t.obs[:-1], np.float32) for t in host.demos]))
        """what D sees of a normalised observation (`--train.imitation.disc-obs`); None: all of it"""
        if self.view is not None:
            self.view.to(host.device)
        self.absorbing = host.absorbing
        """whether D also judges an absorbing state (DAC): its rows then carry a flag"""
        obs_dim = model.obs_dim
        self.feature_dim = obs_dim if self.view is None else self.view.dim
        """the width of `features`"""
        act_in_dim = host.expert.disc_in.shape[1] - obs_dim
        self.act_dim = act_in_dim if cfg.disc_actions else 0
        """the width of the action part of D's rows (0: D judges states alone)"""
        expert_in = host.expert.disc_in
        if self.absorbing or self.view is not None or not self.act_dim:
            expert_in = self.rows(expert_in[:, :obs_dim], expert_in[:, obs_dim:])
        if cfg.relabel_goals:
            expert_in = torch.cat([expert_in, self._relabelled_expert_rows(cfg.relabel_goals)])
        if self.absorbing:
            ends = sum(bool(d.terminated) for d in host.demos)  # one absorbing row per demonstration that terminated
            expert_in = torch.cat([expert_in, self.absorbing_row().expand(ends, -1)])
        self.expert = expert_in
        """D's expert rows: every demonstration step (and its goal-relabelled copies), and with absorbing states the
        absorbing state once per demonstration that terminated"""

    @property
    def dims(self) -> tuple[int, int]:
        """(D's observation part with the absorbing flag, D's action part)"""
        return self.feature_dim + int(self.absorbing), self.act_dim

    def features(self, obs_n: torch.Tensor) -> torch.Tensor:
        """D's view of normalised observations (all of them by default): what an optimal-transport reward compares."""
        return obs_n if self.view is None else self.view(obs_n)

    def rows(self, obs_n: torch.Tensor, act_in: torch.Tensor) -> torch.Tensor:
        """D's input rows for (normalised obs, action as rewards see it) pairs: [obs or its view, (absorbing flag 0,)
        action]."""
        parts = [self.features(obs_n)]
        if self.absorbing:
            parts.append(obs_n.new_zeros(len(obs_n), 1))
        if self.act_dim:
            parts.append(act_in)
        return torch.cat(parts, -1) if len(parts) > 1 else parts[0]

    def absorbing_row(self) -> torch.Tensor:
        """D's input (1, F + 1 + A) for the absorbing state: zero observation and action, flag 1."""
        row = torch.zeros(1, self.feature_dim + 1 + self.act_dim, device=self.host.device)
        row[0, self.feature_dim] = 1.0
        return row

    def _relabelled_expert_rows(self, copies: int) -> torch.Tensor:
        """D's rows of `copies` goal-relabelled copies of every demonstration step (`relabelled_goals`)."""
        h = self.host
        spec = env_spec(h.env_id)
        if spec is None or spec.goal_columns is None:
            raise UserError(f"--train.imitation.relabel-goals needs a goal-conditioned env whose registry entry names "
                            f"its goal columns (digail/FetchPickAndPlace-v4); {h.env_id} has none: set it to 0.")
        # its own generator, so relabelling leaves every other random draw of the run as it was
        obs, acts = relabelled_goals(h.demos, *spec.goal_columns, copies, np.random.default_rng(h.seed))
        obs_n, _, rows = disc_rows(h.model, obs, acts, h.act_input, discrete=h.discrete, device=h.device)
        return self.rows(obs_n, rows[:, obs_n.shape[1]:])
