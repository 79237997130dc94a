"""Reinforcement-learning experts for the continuous-control experiments (paper section 5.3, Table 1).

The paper trained its MuJoCo experts with PPO; so do we, with Stable-Baselines3 (SB3) and observation (and
training-time reward) normalisation by `VecNormalize`. Training is resumable and checkpoints often, because it
is the slowest step of the whole project on a CPU.

Two formats live side by side:

* **Training checkpoints** (`OUT/checkpoints/step_<N>.zip` + `step_<N>.vecnormalize.pkl`): SB3's own format,
  with the value net, the optimiser state and the running statistics, used only by `--resume`.
* **Shipped experts** (`*.pt`): the deterministic actor alone, exported as a plain state_dict together with
  the observation statistics, the env id and the action bounds, loaded with
  `torch.load(..., weights_only=True)`. They are tiny, pickle-free and need neither SB3 nor the training
  folder: `load_expert` rebuilds the actor from them. Every expert folder holds `expert.pt` (the latest
  export) and `best_expert.pt` (the best periodic evaluation); the shipped ones are copies of
  `best_expert.pt` in `digail/experts/weights/`.

Hyperparameters (`EXPERT_SPECS`) are our own choices, written down with their reasons beside each entry. The
pendulum settings follow the spirit of the RL-Zoo's tuned PPO entries for those tasks (short horizon
discount and state-dependent exploration for Pendulum); the locomotion settings follow the large-scale study
of on-policy design choices by Andrychowicz et al. (2021): separate 256x256 tanh policy and value nets,
observation and reward normalisation, a learning rate decayed to zero, GAE(0.95), clip 0.2, and several
parallel environments, which on one CPU core also amortise the per-step network call (8 envs run roughly
twice the steps per second of one).
"""

from __future__ import annotations

import json
import math
import re
import shutil
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import torch
from torch import nn

from digail.errors import UserError
from digail.utils import resolve_device, set_torch_threads, write_json

EXPERT_FORMAT = "digail-expert-v1"
WEIGHTS_DIR = Path(__file__).parent / "weights"
FINAL_EVAL_EPISODES = 50
FINAL_EVAL_SEED = 10_000
"""seed of the first final-evaluation episode (episode i uses seed + i); never used for training"""
PERIODIC_EVAL_SEED = 5_000


@dataclass(frozen=True)
class ExpertSpec:
    """How to train the expert of one environment."""

    steps: int
    """default budget of environment steps"""
    target: float
    """mean return over 50 episodes the expert should reach (the project's acceptance bar)"""
    n_envs: int = 8
    """parallel copies of the env in one process (DummyVecEnv)"""
    ppo: dict[str, Any] = field(default_factory=dict)
    """keyword arguments of `stable_baselines3.PPO` (learning_rate may be ('linear', lr0))"""
    net_arch: tuple[int, ...] = (64, 64)
    """hidden sizes of the policy and of the (separate) value net"""
    activation: str = "tanh"
    """hidden activation: tanh or relu"""
    log_std_init: float = 0.0
    """initial log standard deviation of the Gaussian policy"""
    use_sde: bool = False
    """generalised state-dependent exploration"""
    norm_reward: bool = True
    """normalise rewards during training (evaluation always reports raw returns)"""
    gamma: float = 0.99
    """discount, shared by PPO and the reward normaliser"""
    checkpoint_every: int = 50_000
    """environment steps between resumable checkpoints"""
    eval_every: int = 50_000
    """environment steps between periodic evaluations (which also pick best_expert.pt)"""
    eval_episodes: int = 10
    """episodes of each periodic evaluation"""
    stop_at: float | None = None
    """stop early once a periodic evaluation reaches this mean return (None: run the whole budget)"""


_LOCOMOTION_PPO: dict[str, Any] = {
    "n_steps": 512,  # x 8 envs = 4096 transitions per update
    "batch_size": 256,
    "n_epochs": 10,
    "learning_rate": ("linear", 3e-4),
    "gae_lambda": 0.95,
    "clip_range": 0.2,
    "ent_coef": 0.0,
    "vf_coef": 0.5,
    "max_grad_norm": 0.5,
}

EXPERT_SPECS: dict[str, ExpertSpec] = {
    # Pendulum: a short effective horizon (gamma 0.9) makes the swing-up value easy to learn; gSDE explores
    # smoothly enough to find the swing-up quickly. Optimal play averages about -150 over random starts.
    # With a constant learning rate of 1e-3 our first run peaked at -266 after 1e5 steps and then fell
    # apart, so the rate decays linearly to zero.
    "Pendulum-v1": ExpertSpec(
        steps=200_000, target=-200.0, n_envs=4, gamma=0.9, use_sde=True, norm_reward=False,
        ppo={"n_steps": 1024, "batch_size": 64, "n_epochs": 10, "learning_rate": ("linear", 1e-3),
             "gae_lambda": 0.95, "clip_range": 0.2, "ent_coef": 0.0, "sde_sample_freq": 4},
        checkpoint_every=20_000, eval_every=10_000, eval_episodes=20, stop_at=-170.0),
    # InvertedPendulum: balancing is easy; plain PPO with small nets reaches the 1000-step cap in ~1e5 steps.
    "InvertedPendulum-v5": ExpertSpec(
        steps=300_000, target=1000.0, n_envs=8,
        ppo={"n_steps": 256, "batch_size": 64, "n_epochs": 10, "learning_rate": 3e-4, "gae_lambda": 0.95,
             "clip_range": 0.2, "ent_coef": 0.0},
        checkpoint_every=20_000, eval_every=20_000, eval_episodes=20, stop_at=1000.0),
    "Hopper-v5": ExpertSpec(
        steps=3_000_000, target=3000.0, ppo=_LOCOMOTION_PPO, net_arch=(256, 256), log_std_init=-0.5,
        checkpoint_every=100_000, eval_every=100_000, stop_at=3300.0),
    "Walker2d-v5": ExpertSpec(
        steps=5_000_000, target=4000.0, ppo=_LOCOMOTION_PPO, net_arch=(256, 256), log_std_init=-0.5,
        checkpoint_every=100_000, eval_every=100_000, stop_at=4400.0),
}


def supported_envs() -> list[str]:
    """Env ids with an RL expert recipe."""
    return list(EXPERT_SPECS)


def _spec(env_id: str) -> ExpertSpec:
    if env_id not in EXPERT_SPECS:
        raise UserError(f"no RL expert recipe for {env_id!r}; supported envs are {', '.join(EXPERT_SPECS)} "
                        "(digail's own envs and Fetch have scripted experts, used by `digail demos`).")
    return EXPERT_SPECS[env_id]


def safe_name(env_id: str) -> str:
    """File-system-safe env id (`digail/X-v0` -> `digail-X-v0`)."""
    return env_id.replace("/", "-")


def shipped_expert_path(env_id: str) -> Path:
    """Where the shipped expert of `env_id` lives inside the package."""
    return WEIGHTS_DIR / f"{safe_name(env_id)}.pt"


# ---------------------------------------------------------------------------------------------- the actor
_ACTIVATIONS: dict[str, type[nn.Module]] = {"tanh": nn.Tanh, "relu": nn.ReLU}


class ExpertActor(nn.Module):
    """Deterministic actor of an exported expert: normalise obs, MLP, clip to the action bounds.

    Matches SB3's deterministic PPO prediction: VecNormalize's `clip((obs - mean) / sqrt(var + eps), +-clip)`,
    the policy MLP and the Gaussian mean head, then the action clipped to the env's box.
    """

    obs_mean: torch.Tensor
    obs_var: torch.Tensor
    act_low: torch.Tensor
    act_high: torch.Tensor

    def __init__(self, obs_dim: int, act_dim: int, hidden: tuple[int, ...], activation: str,
                 obs_clip: float = 10.0, obs_eps: float = 1e-8) -> None:
        super().__init__()
        layers: list[nn.Module] = []
        last = obs_dim
        for width in hidden:
            layers += [nn.Linear(last, width), _ACTIVATIONS[activation]()]
            last = width
        layers.append(nn.Linear(last, act_dim))
        self.net = nn.Sequential(*layers)
        self.obs_clip = obs_clip
        self.obs_eps = obs_eps
        self.register_buffer("obs_mean", torch.zeros(obs_dim))
        self.register_buffer("obs_var", torch.ones(obs_dim))
        self.register_buffer("act_low", -torch.ones(act_dim))
        self.register_buffer("act_high", torch.ones(act_dim))

    def forward(self, obs: torch.Tensor) -> torch.Tensor:
        z = (obs - self.obs_mean) / torch.sqrt(self.obs_var + self.obs_eps)
        z = z.clamp(-self.obs_clip, self.obs_clip)
        return torch.maximum(torch.minimum(self.net(z), self.act_high), self.act_low)


def export_expert(model: Any, vec_normalize: Any, env_id: str, path: Path, meta: dict[str, Any]) -> None:
    """Write the deterministic actor of an SB3 PPO `model` and its obs statistics as a pickle-free .pt."""
    policy = model.policy
    hidden = tuple(m.out_features for m in policy.mlp_extractor.policy_net if isinstance(m, nn.Linear))
    activation = "relu" if any(isinstance(m, nn.ReLU) for m in policy.mlp_extractor.policy_net) else "tanh"
    obs_dim = int(np.prod(model.observation_space.shape))
    act_dim = int(np.prod(model.action_space.shape))
    actor = ExpertActor(obs_dim, act_dim, hidden, activation, float(vec_normalize.clip_obs),
                        float(vec_normalize.epsilon))
    linears = [m for m in policy.mlp_extractor.policy_net if isinstance(m, nn.Linear)] + [policy.action_net]
    ours = [m for m in actor.net if isinstance(m, nn.Linear)]
    with torch.no_grad():
        for dst, src in zip(ours, linears, strict=True):
            dst.weight.copy_(src.weight.cpu())
            dst.bias.copy_(src.bias.cpu())
        if vec_normalize.norm_obs:
            actor.obs_mean.copy_(torch.as_tensor(vec_normalize.obs_rms.mean, dtype=torch.float32))
            actor.obs_var.copy_(torch.as_tensor(vec_normalize.obs_rms.var, dtype=torch.float32))
        actor.act_low.copy_(torch.as_tensor(model.action_space.low, dtype=torch.float32))
        actor.act_high.copy_(torch.as_tensor(model.action_space.high, dtype=torch.float32))
    payload = {
        "format": EXPERT_FORMAT,
        "env_id": env_id,
        "algo": "ppo",
        "obs_dim": obs_dim,
        "act_dim": act_dim,
        "hidden": list(hidden),
        "activation": activation,
        "obs_clip": float(vec_normalize.clip_obs),
        "obs_eps": float(vec_normalize.epsilon),
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
                        payload["activation"], payload["obs_clip"], payload["obs_eps"])
    actor.load_state_dict(payload["state_dict"])
    actor.eval()
    meta = json.loads(payload.get("meta", "{}"))
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
    return [env_id for env_id in EXPERT_SPECS if shipped_expert_path(env_id).is_file()]


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


# ---------------------------------------------------------------------------------------------- training
_STEP_RE = re.compile(r"step_(\d+)\.zip$")


def _checkpoints(folder: Path) -> list[tuple[int, Path]]:
    found = [(int(m.group(1)), p) for p in folder.glob("step_*.zip") if (m := _STEP_RE.search(p.name))]
    return sorted(found)


def _learning_rate(value: Any) -> Any:
    if isinstance(value, tuple) and value[0] == "linear":
        lr0 = float(value[1])
        return lambda progress_remaining: lr0 * progress_remaining
    return value


def _make_vec_env(env_id: str, spec: ExpertSpec, seed: int) -> Any:
    from stable_baselines3.common.env_util import make_vec_env

    from digail.envs import register_envs

    register_envs()
    return make_vec_env(env_id, n_envs=spec.n_envs, seed=seed)


def _build_model(env_id: str, spec: ExpertSpec, seed: int, device: str) -> tuple[Any, Any]:
    from stable_baselines3 import PPO
    from stable_baselines3.common.vec_env import VecNormalize

    venv = VecNormalize(_make_vec_env(env_id, spec, seed), norm_obs=True, norm_reward=spec.norm_reward,
                        gamma=spec.gamma)
    kwargs = dict(spec.ppo)
    kwargs["learning_rate"] = _learning_rate(kwargs.get("learning_rate", 3e-4))
    policy_kwargs = {
        "net_arch": {"pi": list(spec.net_arch), "vf": list(spec.net_arch)},
        "activation_fn": _ACTIVATIONS[spec.activation],
        "log_std_init": spec.log_std_init,
    }
    model = PPO("MlpPolicy", venv, gamma=spec.gamma, use_sde=spec.use_sde, policy_kwargs=policy_kwargs,
                seed=seed, device=device, verbose=0, **kwargs)
    return model, venv


def _load_model(env_id: str, spec: ExpertSpec, zip_path: Path, seed: int, device: str) -> tuple[Any, Any]:
    from stable_baselines3 import PPO
    from stable_baselines3.common.vec_env import VecNormalize

    stats = str(zip_path.with_suffix(".vecnormalize.pkl"))
    venv = VecNormalize.load(stats, _make_vec_env(env_id, spec, seed))
    venv.training = True
    custom = {"learning_rate": _learning_rate(spec.ppo.get("learning_rate", 3e-4))}
    model = PPO.load(str(zip_path), env=venv, device=device, custom_objects=custom)
    return model, venv


def _progress_callback(total: int, spec: ExpertSpec, env_id: str, out: Path, seed: int,
                       t_start: float) -> Any:
    """SB3 callback: progress bar, resumable checkpoints, periodic evaluation, best export, early stop."""
    from stable_baselines3.common.callbacks import BaseCallback
    from tqdm import tqdm

    class _Callback(BaseCallback):
        def __init__(self) -> None:
            super().__init__()
            self.bar: Any = None
            self.next_ckpt = 0
            self.next_eval = 0
            self.history: list[dict[str, Any]] = []

        def _on_training_start(self) -> None:
            done = self.num_timesteps
            self.bar = tqdm(total=total, initial=done, unit="step", dynamic_ncols=True, desc=env_id,
                            mininterval=5.0)
            self.next_ckpt = (done // spec.checkpoint_every + 1) * spec.checkpoint_every
            self.next_eval = (done // spec.eval_every + 1) * spec.eval_every
            state_file = out / "progress.json"
            if state_file.exists():
                self.history = json.loads(state_file.read_text()).get("evals", [])

        def _on_step(self) -> bool:
            self.bar.update(self.training_env.num_envs)
            keep_going = True
            if self.num_timesteps >= self.next_eval:
                keep_going = self._evaluate()
                self.next_eval += spec.eval_every
            if self.num_timesteps >= self.next_ckpt:
                self._checkpoint()
                self.next_ckpt += spec.checkpoint_every
            return keep_going

        def _on_rollout_end(self) -> None:
            buf = self.model.ep_info_buffer
            if buf:
                self.bar.set_postfix(ret=f"{np.mean([e['r'] for e in buf]):.1f}",
                                     len=f"{np.mean([e['l'] for e in buf]):.0f}", refresh=False)

        def _meta(self) -> dict[str, Any]:
            return {"env_id": env_id, "steps": int(self.num_timesteps), "seed": seed,
                    "wall_s": _wall(out, t_start)}

        def _evaluate(self) -> bool:
            export_expert(self.model, self.training_env, env_id, out / "expert.pt", self._meta())
            policy = load_expert(env_id, out / "expert.pt")
            res = evaluate_expert(env_id, policy, spec.eval_episodes, PERIODIC_EVAL_SEED)
            entry = {"steps": int(self.num_timesteps), "mean": res["mean"], "std": res["std"],
                     "wall_s": _wall(out, t_start)}
            self.history.append(entry)
            best = max(self.history, key=lambda e: e["mean"])
            if best is entry:
                shutil.copyfile(out / "expert.pt", out / "best_expert.pt")
            self.bar.write(f"[{env_id}] step {entry['steps']}: eval {res['mean']:.1f} +- {res['std']:.1f} "
                           f"(best {best['mean']:.1f} @ {best['steps']})")
            self._save_progress()
            return spec.stop_at is None or res["mean"] < spec.stop_at

        def _save_progress(self) -> None:
            write_json(out / "progress.json", {"env_id": env_id, "seed": seed,
                                               "steps": int(self.num_timesteps),
                                               "wall_s": _wall(out, t_start), "evals": self.history})

        def _checkpoint(self) -> None:
            ckpt_dir = out / "checkpoints"
            ckpt_dir.mkdir(parents=True, exist_ok=True)
            stem = ckpt_dir / f"step_{self.num_timesteps}"
            self.model.save(str(stem) + ".zip")
            vec_normalize: Any = self.training_env  # a VecNormalize, which adds save()
            vec_normalize.save(str(stem) + ".vecnormalize.pkl")
            self._save_progress()
            for _, old in _checkpoints(ckpt_dir)[:-2]:  # keep the last two
                old.unlink(missing_ok=True)
                old.with_suffix(".vecnormalize.pkl").unlink(missing_ok=True)

        def _on_training_end(self) -> None:
            self._checkpoint()
            self.bar.close()

    return _Callback()


def _wall(out: Path, t_start: float) -> float:
    """Training wall time including earlier (resumed) sessions."""
    previous = 0.0
    marker = out / "wall_before_resume.txt"
    if marker.exists():
        previous = float(marker.read_text())
    return round(previous + time.time() - t_start, 1)


@dataclass(frozen=True)
class ExpertRun:
    """One expert training run (what `digail expert` asks for)."""

    env: str
    """environment id with a recipe in `EXPERT_SPECS`"""
    out: Path | None = None
    """expert folder (default: experts_work/<env>)"""
    steps: int | None = None
    """environment steps (default: the recipe's budget)"""
    resume: bool = False
    """continue from the folder's last checkpoint"""
    seed: int = 0
    """random seed"""
    device: str = "cpu"
    """torch device for SB3"""


def train_expert(args: ExpertRun) -> Path:
    """Train (or resume) a PPO expert, then evaluate it on 50 fresh episodes.

    Writes into OUT: `checkpoints/` (resumable SB3 checkpoints), `expert.pt` / `best_expert.pt` (exported
    actors), `progress.json` (periodic evaluations) and `eval.json` (final 50-episode evaluation of
    `best_expert.pt`, deterministic actions). Returns OUT.
    """
    spec = _spec(args.env)
    device = str(resolve_device(args.device))  # an unavailable CUDA is a UserError here, not deep inside SB3
    set_torch_threads(1)
    out = Path(args.out) if args.out is not None else Path("experts_work") / safe_name(args.env)
    total = int(args.steps if args.steps is not None else spec.steps)
    if total <= 0:
        raise UserError(f"--steps must be positive, got {total}.")
    ckpt_dir = out / "checkpoints"
    existing = _checkpoints(ckpt_dir) if ckpt_dir.is_dir() else []
    if args.resume:
        if not existing:
            raise UserError(f"nothing to resume in {out}: no checkpoints/step_*.zip; drop --resume to start "
                            "anew.")
        progress = json.loads((out / "progress.json").read_text()) if (out / "progress.json").exists() else {}
        if progress.get("env_id", args.env) != args.env:
            raise UserError(f"{out} holds an expert for {progress['env_id']!r}, not {args.env!r}; "
                            "resume with the same env or choose another --out.")
        (out / "wall_before_resume.txt").write_text(str(progress.get("wall_s", 0.0)))
        model, _ = _load_model(args.env, spec, existing[-1][1], args.seed, device)
    else:
        if existing or (out / "expert.pt").exists():
            raise UserError(f"{out} already holds a training run; pass --resume to continue it or choose "
                            "another --out.")
        out.mkdir(parents=True, exist_ok=True)
        (out / "wall_before_resume.txt").unlink(missing_ok=True)
        model, _ = _build_model(args.env, spec, args.seed, device)
    ppo_kwargs = {k: str(v) if isinstance(v, tuple) else v for k, v in spec.ppo.items()}
    write_json(out / "config.json", {"env_id": args.env, "steps": total, "seed": args.seed,
                                     "spec": {**spec.__dict__, "ppo": ppo_kwargs}})
    t_start = time.time()
    remaining = total - int(model.num_timesteps)
    if remaining > 0:
        callback = _progress_callback(total, spec, args.env, out, args.seed, t_start)
        model.learn(total_timesteps=remaining, callback=callback, reset_num_timesteps=not args.resume)
    if not (out / "best_expert.pt").exists():
        export_expert(model, model.get_env(), args.env, out / "expert.pt",
                      {"env_id": args.env, "steps": int(model.num_timesteps), "seed": args.seed})
        shutil.copyfile(out / "expert.pt", out / "best_expert.pt")
    result = evaluate_expert(args.env, load_expert(args.env, out / "best_expert.pt"), FINAL_EVAL_EPISODES,
                             FINAL_EVAL_SEED)
    _, meta = load_expert_actor(args.env, out / "best_expert.pt")
    result.update({"deterministic": True, "expert": str(out / "best_expert.pt"),
                   "expert_steps": meta.get("steps"),
                   "total_steps": int(model.num_timesteps), "wall_s": _wall(out, t_start),
                   "target": spec.target, "reached_target": bool(result["mean"] >= spec.target)})
    write_json(out / "eval.json", result)
    print(f"{args.env}: {result['mean']:.1f} +- {result['std']:.1f} over {FINAL_EVAL_EPISODES} episodes "
          f"(best export at step {meta.get('steps')}; target {spec.target:g}); wrote {out / 'eval.json'}")
    if not math.isfinite(result["mean"]):
        raise RuntimeError("the final evaluation returned a non-finite mean")
    return out


expert_command = train_expert
"""the name this function had before the `commands` layer (`digail.commands.expert` runs it)"""


# ---------------------------------------------------------------------------------------------- shipping
RECORD_FILE = WEIGHTS_DIR / "EXPERTS.json"
"""What ships in `weights/`: per env, the expert's 50-episode evaluation and how it was made."""


def _read_record() -> dict[str, Any]:
    return json.loads(RECORD_FILE.read_text()) if RECORD_FILE.is_file() else {}


def record_expert(env_id: str, entry: dict[str, Any]) -> None:
    """Set `env_id`'s entry in `weights/EXPERTS.json` (keys kept sorted so diffs stay small)."""
    record = _read_record()
    record[env_id] = entry
    write_json(RECORD_FILE, dict(sorted(record.items())))
    RECORD_FILE.chmod(0o644)


def shipped_expert_eval(env_id: str) -> dict[str, Any] | None:
    """The recorded evaluation (50 fresh episodes) of the expert shipped for `env_id`, if any."""
    entry = _read_record().get(env_id)
    return None if entry is None else entry.get("eval")


def ship_expert(env_id: str, folder: str | Path) -> Path:
    """Copy a finished run's `best_expert.pt` into the package and record its `eval.json` in EXPERTS.json.

    Raises:
        UserError: the folder holds no finished run (no eval.json) or a run for another env.
    """
    folder = Path(folder)
    if not (folder / "eval.json").is_file() or not (folder / "best_expert.pt").is_file():
        raise UserError(f"{folder} holds no finished expert run (eval.json and best_expert.pt); finish it "
                        f"with `digail expert {env_id} --out {folder} --resume` first.")
    result = json.loads((folder / "eval.json").read_text())
    _, meta = load_expert_actor(env_id, folder / "best_expert.pt")  # refuses another env's expert
    dest = shipped_expert_path(env_id)
    dest.parent.mkdir(parents=True, exist_ok=True)
    shutil.copyfile(folder / "best_expert.pt", dest)
    seed = meta.get("seed", 0)
    config = json.loads((folder / "config.json").read_text()) if (folder / "config.json").is_file() else {}
    record_expert(env_id, {
        "file": dest.name,
        "kind": "rl",
        "algo": "ppo (stable-baselines3)",
        "command": f"digail expert {env_id} --out experts_work/{safe_name(env_id)} --seed {seed}",
        "eval": {k: result[k] for k in ("episodes", "seed", "mean", "std", "min", "max", "mean_length")}
        | {"deterministic": True},
        "expert_steps": meta.get("steps"),
        "total_steps": result.get("total_steps"),
        "budget_steps": config.get("steps"),
        "wall_s": result.get("wall_s"),
        "target": result.get("target"),
        "reached_target": result.get("reached_target"),
    })
    return dest
