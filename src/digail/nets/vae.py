"""The hierarchical model of paper section 3.1: macro-policy q, learned prior p, sub-task policy pi.

`HierarchicalPolicy` is what every run folder stores: the VAE trains all of it; GAIL trains `pi` with `q` frozen.
"""

from __future__ import annotations

from collections.abc import Sequence

import torch
from torch import nn

from digail.nets.mlp import mlp
from digail.nets.normalizer import ObsNormalizer
from digail.nets.policy import ActionSpec, SubtaskPolicy


class MacroPolicy(nn.Module):
    """Encoder / macro-policy q_phi(c_t | s_t, c_{t-1}): K logits.

    `prev` is the previous code as a (relaxed) one-hot, or the zero vector at an episode start (c_{-1}).
    """

    def __init__(self, obs_dim: int, codes: int, hidden: Sequence[int] = (64, 64)) -> None:
        super().__init__()
        self.codes = codes
        self.net = mlp(obs_dim + codes, codes, hidden)

    def forward(self, obs_n: torch.Tensor, prev: torch.Tensor) -> torch.Tensor:
        return self.net(torch.cat([obs_n, prev], -1))


class CodePrior(nn.Module):
    """Learned prior p_psi(c_t | c_{t-1}): a (K + 1) x K table of logits; the last row is the start input."""

    def __init__(self, codes: int, learn: bool = True) -> None:
        super().__init__()
        self.codes = codes
        self.table = nn.Parameter(torch.zeros(codes + 1, codes), requires_grad=learn)

    def forward(self, prev: torch.Tensor) -> torch.Tensor:
        """Logits for (relaxed) one-hot `prev` codes; an all-zero `prev` selects the start row."""
        is_start = (prev.abs().sum(-1, keepdim=True) == 0).float()
        return prev @ self.table[:-1] + is_start * self.table[-1]


class HierarchicalPolicy(nn.Module):
    """Normaliser + macro-policy q + prior p + sub-task policy pi, all on raw observations from outside."""

    def __init__(self, obs_dim: int, codes: int, action: ActionSpec, hidden: Sequence[int] = (64, 64),
                 learn_prior: bool = True, decoder_obs: tuple[int, int] | None = None) -> None:
        super().__init__()
        self.obs_dim, self.codes, self.action = obs_dim, codes, action
        # kept so that checkpoints can rebuild the model
        self.hidden, self.learn_prior, self.decoder_obs = tuple(hidden), learn_prior, decoder_obs
        self.normalizer = ObsNormalizer(obs_dim)
        self.q = MacroPolicy(obs_dim, codes, hidden)
        self.prior = CodePrior(codes, learn_prior)
        self.pi = SubtaskPolicy(obs_dim, codes, action, hidden, decoder_obs=decoder_obs)

    @torch.no_grad()
    def next_code(self, obs_n: torch.Tensor, prev: torch.Tensor) -> torch.Tensor:
        """c_t = argmax q(. | s_t, c_{t-1}) for a batch of normalised states and one-hot previous codes (ints)."""
        return self.q(obs_n, prev).argmax(-1)
