"""PPO (Schulman et al., 2017) with GAE: the advantage estimator and a pure update step."""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
import torch
from torch import nn

from digail.config import PPOConfig
from digail.nets.critic import ValueNet
from digail.nets.policy import SubtaskPolicy


@torch.no_grad()
def compute_gae(rews: torch.Tensor, values: torch.Tensor, terminated: torch.Tensor, truncated: torch.Tensor,
                final_values: torch.Tensor, last_values: torch.Tensor, gamma: float, lam: float
                ) -> tuple[torch.Tensor, torch.Tensor]:
    """Generalised advantage estimation over a (T, N) rollout; returns (advantages, value targets).

    `terminated[t]` / `truncated[t]` say the episode ended after step t. A terminal state is worth 0. A time-limit
    truncation is *not* terminal: the value of the true final observation, `final_values[t]`, is bootstrapped
    (the env has already been reset, so `values[t + 1]` belongs to a new episode and is cut off in both cases).
    `last_values` is V of the observation after the last step, used where the rollout stops mid-episode.
    """
    # A NumPy loop: T small steps cost far less outside torch's per-op dispatch (~10x here).
    r, v = rews.cpu().numpy(), values.cpu().numpy()
    not_done = 1.0 - (terminated | truncated).cpu().numpy().astype(np.float32)
    boot = final_values.cpu().numpy() * truncated.cpu().numpy()
    nxt = np.concatenate([v[1:], last_values.cpu().numpy()[None]], 0)
    deltas = r + gamma * (nxt * not_done + boot) - v
    adv_np = np.zeros_like(r)
    gae = np.zeros_like(r[0])
    for t in range(len(r) - 1, -1, -1):
        gae = deltas[t] + gamma * lam * not_done[t] * gae
        adv_np[t] = gae
    adv = torch.from_numpy(adv_np).to(rews.device)
    return adv, adv + values


@dataclass(frozen=True)
class PPOBatch:
    """Flattened rollout: `b_` tensors of length B (obs already normalised, codes one-hot)."""

    obs: torch.Tensor
    codes: torch.Tensor
    acts: torch.Tensor
    logp: torch.Tensor
    adv: torch.Tensor
    returns: torch.Tensor

    def __len__(self) -> int:
        return len(self.obs)


def ppo_update(policy: SubtaskPolicy, value: ValueNet, optimizer: torch.optim.Optimizer, batch: PPOBatch,
               cfg: PPOConfig, generator: torch.Generator,
               bc_loss: Callable[[], torch.Tensor] | None = None, bc_weight: float = 0.0,
               train_policy: bool = True) -> dict[str, float]:
    """Clipped-surrogate PPO epochs over `batch`; returns mean losses and diagnostics.

    Pure apart from the parameters and optimiser it is handed: no hidden state, no env access. `bc_loss`, when
    given, is evaluated once per minibatch on fresh expert samples and added with `bc_weight`. With
    `train_policy=False` only the value loss is minimised (critic warm-up).
    """
    params = [p for g in optimizer.param_groups for p in g["params"]]
    n = len(batch)
    mb = min(cfg.minibatch_size, n)
    stats = {"policy": 0.0, "value": 0.0, "entropy": 0.0, "approx_kl": 0.0, "clip_frac": 0.0, "bc": 0.0}
    updates = 0
    for _ in range(cfg.epochs):
        perm = torch.randperm(n, generator=generator)
        # one gather per epoch: the minibatches are then contiguous views (the same rows as indexing each one)
        e_obs, e_codes, e_acts, e_logp, e_adv, e_returns = (
            t[perm] for t in (batch.obs, batch.codes, batch.acts, batch.logp, batch.adv, batch.returns))
        kl_sum, kl_count = 0.0, 0
        for start in range(0, n - mb + 1, mb):
            mb_obs, mb_codes = e_obs[start:start + mb], e_codes[start:start + mb]
            logp, entropy = policy.log_prob_entropy(mb_obs, mb_codes, e_acts[start:start + mb])
            log_ratio = logp - e_logp[start:start + mb]
            ratio = log_ratio.exp()
            adv = e_adv[start:start + mb]
            if cfg.norm_adv and mb > 1:
                adv = (adv - adv.mean()) / (adv.std() + 1e-8)
            pg_loss = -torch.min(ratio * adv, ratio.clamp(1 - cfg.clip, 1 + cfg.clip) * adv).mean()
            v_loss = 0.5 * (value(mb_obs, mb_codes) - e_returns[start:start + mb]).pow(2).mean()
            entropy = entropy.mean()
            loss = pg_loss + cfg.vf_coef * v_loss - cfg.ent_coef * entropy if train_policy else v_loss
            if train_policy and bc_loss is not None and bc_weight > 0:
                bc = bc_loss()
                loss = loss + bc_weight * bc
                stats["bc"] += bc.item()
            optimizer.zero_grad(set_to_none=True)
            loss.backward()
            nn.utils.clip_grad_norm_(params, cfg.max_grad_norm)
            optimizer.step()
            with torch.no_grad():
                approx_kl = float(((ratio - 1) - log_ratio).mean())
                stats["clip_frac"] += float(((ratio - 1).abs() > cfg.clip).float().mean())
            stats["policy"] += pg_loss.item()
            stats["value"] += v_loss.item()
            stats["entropy"] += entropy.item()
            stats["approx_kl"] += approx_kl
            kl_sum, kl_count = kl_sum + approx_kl, kl_count + 1
            updates += 1
        if cfg.target_kl is not None and kl_count and kl_sum / kl_count > cfg.target_kl:
            break
    return {k: v / max(updates, 1) for k, v in stats.items()}
