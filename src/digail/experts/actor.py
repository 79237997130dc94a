"""The SB3-free expert: the exported deterministic actor, loading it, and measuring it on seeded episodes."""

from __future__ import annotations

import json
import math
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np
import torch
from torch import nn

from digail.errors import UserError
from digail.experts.recipes import EXPERT_FORMAT, rl_expert_envs, shipped_expert_path

ACTIVATIONS: dict[str, type[nn.Module]] = {"tanh": nn.Tanh, "relu": nn.ReLU}


class ExpertActor(nn.Module):
    """Deterministic actor of an exported expert: normalise obs, MLP, squash (SAC) or clip to the action bounds.

    Matches SB3's deterministic PPO prediction: VecNormalize's `clip((obs - mean) / sqrt(var + eps), +-clip)`,
    the policy MLP and the Gaussian mean head, then the action clipped to the env's box. With `squash` it
    matches SAC's instead: `tanh` of the mean head, rescaled from [-1, 1] to the box (SAC exports keep the
    identity statistics, no clip and no eps, so the observations pass unchanged).
    """

    obs_mean: torch.Tensor
    obs_var: torch.Tensor
    act_low: torch.Tensor
    act_high: torch.Tensor

    def __init__(self, obs_dim: int, act_dim: int, hidden: tuple[int, ...], activation: str,
                 obs_clip: float = 10.0, obs_eps: float = 1e-8, squash: bool = False) -> None:
        super().__init__()
        layers: list[nn.Module] = []
        last = obs_dim
        for width in hidden:
            layers += [nn.Linear(last, width), ACTIVATIONS[activation]()]
            last = width
        layers.append(nn.Linear(last, act_dim))
        self.net = nn.Sequential(*layers)
        self.obs_clip = obs_clip
        self.obs_eps = obs_eps
        self.squash = squash
        self.register_buffer("obs_mean", torch.zeros(obs_dim))
        self.register_buffer("obs_var", torch.ones(obs_dim))
        self.register_buffer("act_low", -torch.ones(act_dim))
        self.register_buffer("act_high", torch.ones(act_dim))

    def forward(self, obs: torch.Tensor) -> torch.Tensor:
        z = (obs - self.obs_mean) / torch.sqrt(self.obs_var + self.obs_eps)
        z = z.clamp(-self.obs_clip, self.obs_clip)
        act = self.net(z)
        if self.squash:
            act = self.act_low + 0.5 * (torch.tanh(act) + 1.0) * (self.act_high - self.act_low)
        return torch.maximum(torch.minimum(act, self.act_high), self.act_low)


def export_expert(model: Any, vec_normalize: Any, env_id: str, path: Path, meta: dict[str, Any]) -> None:
    """Write the deterministic actor of an SB3 PPO or SAC `model` (and PPO's obs statistics, from the
    `VecNormalize` wrapper `vec_normalize`; SAC's env is not one) as a pickle-free .pt.

    Reads the SB3 objects by their attributes, so this module needs no SB3 import: a SAC policy has an
    `actor` (`latent_pi` MLP, `mu` head; no gSDE), a PPO one an `mlp_extractor` and an `action_net`; only a
    `VecNormalize` has `obs_rms`.
    """
    algo = "sac" if hasattr(model.policy, "actor") else "ppo"
    if algo == "sac":
        hidden_net, head = model.policy.actor.latent_pi, model.policy.actor.mu
    else:
        hidden_net, head = model.policy.mlp_extractor.policy_net, model.policy.action_net
    normalizer = vec_normalize if hasattr(vec_normalize, "obs_rms") else None
    obs_clip = float(normalizer.clip_obs) if normalizer is not None else math.inf
    obs_eps = float(normalizer.epsilon) if normalizer is not None else 0.0
    hidden = tuple(m.out_features for m in hidden_net if isinstance(m, nn.Linear))
    activation = "relu" if any(isinstance(m, nn.ReLU) for m in hidden_net) else "tanh"
    obs_dim = int(np.prod(model.observation_space.shape))
    act_dim = int(np.prod(model.action_space.shape))
    actor = ExpertActor(obs_dim, act_dim, hidden, activation, obs_clip, obs_eps, squash=algo == "sac")
    linears = [m for m in hidden_net if isinstance(m, nn.Linear)] + [head]
    ours = [m for m in actor.net if isinstance(m, nn.Linear)]
    with torch.no_grad():
        for dst, src in zip(ours, linears, strict=True):
            dst.weight.copy_(src.weight.cpu())
            dst.bias.copy_(src.bias.cpu())
        if normalizer is not None and normalizer.norm_obs:
            rms: Any = normalizer.obs_rms  # one RunningMeanStd for a Box observation space
            actor.obs_mean.copy_(torch.as_tensor(rms.mean, dtype=torch.float32))
            actor.obs_var.copy_(torch.as_tensor(rms.var, dtype=torch.float32))
        actor.act_low.copy_(torch.as_tensor(model.action_space.low, dtype=torch.float32))
        actor.act_high.copy_(torch.as_tensor(model.action_space.high, dtype=torch.float32))
    payload = {
        "format": EXPERT_FORMAT,
        "env_id": env_id,
        "algo": algo,
        "obs_dim": obs_dim,
        "act_dim": act_dim,
        "hidden": list(hidden),
        "activation": activation,
        "obs_clip": obs_clip,
        "obs_eps": obs_eps,
        "squash": algo == "sac",
        "state_dict": {k: v.detach().clone() for k, v in actor.state_dict().items()},
        "meta": json.dumps(meta),
    }
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(f".{path.name}.tmp")
    torch.save(payload, tmp)
    tmp.replace(path)


def load_expert_actor(env_id: str, path: str | Path | None = None) -> tuple[ExpertActor, dict[str, Any]]:
    """Rebuild the exported actor of `env_id` (the shipped one unless `path`); also return its metadata."""
    path = Path(path) if path is not None else shipped_expert_path(env_id)
    if path is None or not path.is_file():
        if path == shipped_expert_path(env_id):
            raise UserError(f"no shipped expert for {env_id!r}; train one with `digail expert {env_id}` "
                            f"(experts ship for {', '.join(shipped_envs()) or 'no env yet'}).")
        raise UserError(f"expert file {path} does not exist; pass the .pt written by `digail expert`.")
    try:
        payload = torch.load(path, map_location="cpu", weights_only=True)
    except Exception as exc:
        raise UserError(f"{path} is not a digail expert file ({type(exc).__name__}); pass the expert.pt or "
                        "best_expert.pt written by `digail expert`.") from exc
    if not isinstance(payload, dict) or payload.get("format") != EXPERT_FORMAT:
        raise UserError(f"{path} is not a digail expert file; pass the expert.pt or best_expert.pt written "
                        "by `digail expert`.")
    if payload["env_id"] != env_id:
        raise UserError(f"expert {path} was trained for {payload['env_id']!r}, not {env_id!r}; pass an "
                        f"expert made for {env_id}.")
    actor = ExpertActor(payload["obs_dim"], payload["act_dim"], tuple(payload["hidden"]),
                        payload["activation"], payload["obs_clip"], payload["obs_eps"],
                        squash=bool(payload.get("squash", False)))  # PPO exports before SAC carry no "squash"
    actor.load_state_dict(payload["state_dict"])
    actor.eval()
    meta = json.loads(payload.get("meta", "{}"))
    meta.setdefault("algo", payload.get("algo", "ppo"))
    return actor, meta


def load_expert(env_id: str, path: str | Path | None = None) -> Callable[[np.ndarray], np.ndarray]:
    """Deterministic expert policy for `env_id` from the shipped weights (or `path`).

    The returned function maps a batch of raw observations `(N, obs_dim)` to actions `(N, act_dim)` (a single
    observation `(obs_dim,)` gives one action `(act_dim,)`), applying the saved normalisation statistics.

    Raises:
        UserError: no expert ships for `env_id`, the file is not an expert, or it was made for another env.
    """
    actor, _ = load_expert_actor(env_id, path)
    obs_dim = actor.obs_mean.shape[0]

    def policy(obs: np.ndarray) -> np.ndarray:
        obs = np.asarray(obs, dtype=np.float32)
        single = obs.ndim == 1
        batch = obs.reshape(1 if single else len(obs), -1)
        if batch.shape[1] != obs_dim:
            raise UserError(f"the {env_id} expert expects observations of size {obs_dim}, got "
                            f"{batch.shape[1]}; use the env the expert was trained on.")
        with torch.no_grad():
            act = actor(torch.from_numpy(batch)).numpy()
        return act[0] if single else act

    return policy


def shipped_envs() -> list[str]:
    """Env ids whose expert ships with the package."""
    return [env_id for env_id in rl_expert_envs() if shipped_expert_path(env_id).is_file()]


def evaluate_expert(env_id: str, policy: Callable[[np.ndarray], np.ndarray], episodes: int,
                    seed: int) -> dict[str, Any]:
    """Roll `policy` for `episodes` episodes (episode i reset with seed + i); raw undiscounted returns."""
    from digail.envs import make_env
    from digail.envs.episodes import play_episodes

    env = make_env(env_id)
    eps = play_episodes(env, lambda env, obs: policy(obs), episodes, seed)
    env.close()
    returns, lengths = [e.ret for e in eps], [e.length for e in eps]
    return {"env_id": env_id, "episodes": episodes, "seed": seed, "mean": float(np.mean(returns)),
            "std": float(np.std(returns)), "min": float(np.min(returns)), "max": float(np.max(returns)),
            "mean_length": float(np.mean(lengths)), "returns": returns}
