"""Training an expert with Stable-Baselines3: the model, resumable checkpoints, periodic evaluations, the export."""

from __future__ import annotations

import io
import json
import math
import re
import shutil
import sys
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from digail.checkpoint import load_weights, run_config, write_run_config
from digail.config import to_dict
from digail.errors import UserError
from digail.experts.actor import ACTIVATIONS, evaluate_expert, export_expert, load_expert, load_expert_actor
from digail.experts.recipes import (
    FINAL_EVAL_EPISODES,
    FINAL_EVAL_SEED,
    PERIODIC_EVAL_SEED,
    ExpertSpec,
    safe_name,
    spec_for,
)
from digail.fsio import atomic_write_bytes, check_output, digail_made, run_dir_lock, write_json, write_marker
from digail.utils import one_line, progress_bar, resolve_device, set_torch_threads

_STEP_RE = re.compile(r"step_(\d+)\.pt$")
CHECKPOINT_FORMAT = "digail-sb3-checkpoint"
"""`format` of a training checkpoint (`checkpoints/step_<N>.pt`)"""
REPLAY_ARRAYS = ("observations", "next_observations", "actions", "rewards", "dones", "timeouts")
"""the arrays of SB3's `ReplayBuffer` a SAC checkpoint keeps (their filled rows)"""


def _checkpoints(folder: Path) -> list[tuple[int, Path]]:
    found = [(int(m.group(1)), p) for p in folder.glob("step_*.pt") if (m := _STEP_RE.search(p.name))]
    return sorted(found)


def _companions(ckpt: Path) -> tuple[Path, Path]:
    """The normaliser statistics (PPO) and the replay buffer (SAC) files beside a checkpoint."""
    return ckpt.with_suffix(".vecnormalize.npz"), ckpt.with_suffix(".replay.npz")


def _npz_bytes(arrays: dict[str, Any]) -> bytes:
    buf = io.BytesIO()
    np.savez(buf, allow_pickle=False, **{k: np.asarray(v) for k, v in arrays.items()})
    return buf.getvalue()


def save_checkpoint(model: Any, venv: Any, stem: Path) -> Path:
    """Write a resumable training checkpoint without pickle: `stem.pt` holds the state_dicts (networks and
    optimisers, as SB3's `get_parameters` names them), SAC's entropy coefficient and the counters, saved as
    tensors and plain data; PPO's `VecNormalize` statistics go to `stem.vecnormalize.npz` and SAC's replay
    buffer (its filled rows) to `stem.replay.npz`. Returns the .pt path."""
    import torch

    ckpt = stem.with_suffix(".pt")
    stats, replay = _companions(ckpt)
    if hasattr(venv, "obs_rms"):
        atomic_write_bytes(stats, _npz_bytes({
            "obs_mean": venv.obs_rms.mean, "obs_var": venv.obs_rms.var, "obs_count": np.float64(venv.obs_rms.count),
            "ret_mean": venv.ret_rms.mean, "ret_var": venv.ret_rms.var, "ret_count": np.float64(venv.ret_rms.count)}))
    buffer = getattr(model, "replay_buffer", None)
    if buffer is not None:
        filled = buffer.buffer_size if buffer.full else buffer.pos
        arrays = {k: getattr(buffer, k)[:filled] for k in REPLAY_ARRAYS if getattr(buffer, k, None) is not None}
        atomic_write_bytes(replay, _npz_bytes({**arrays, "pos": np.int64(buffer.pos), "full": np.bool_(buffer.full)}))
    ent = getattr(model, "log_ent_coef", None)
    payload = {
        "format": CHECKPOINT_FORMAT,
        "algo": "sac" if buffer is not None else "ppo",
        "params": model.get_parameters(),
        "log_ent_coef": ent.detach().cpu() if isinstance(ent, torch.Tensor) else None,
        "num_timesteps": int(model.num_timesteps),
        "n_updates": int(getattr(model, "_n_updates", 0)),
        "episode_num": int(getattr(model, "_episode_num", 0)),
    }
    buf = io.BytesIO()
    torch.save(payload, buf)
    atomic_write_bytes(ckpt, buf.getvalue())  # last: a checkpoint is complete once its .pt exists
    return ckpt


def _read_npz(path: Path, what: str) -> dict[str, np.ndarray]:
    """The arrays of an .npz, read without pickle; every failure one sentence."""
    try:
        with np.load(path, allow_pickle=False) as z:
            return {k: z[k] for k in z.files}
    except FileNotFoundError:
        raise UserError(f"the {what} file {path} is missing; restore it or start the expert again without "
                        "--resume.") from None
    except Exception as exc:  # truncated, not an npz, or object arrays (which would need pickle)
        raise UserError(f"the {what} file {path} is corrupt or not plain arrays ({type(exc).__name__}); restore "
                        "it or start the expert again without --resume.") from None


def load_checkpoint(model: Any, venv: Any, ckpt: Path, device: str) -> None:
    """Restore what `save_checkpoint` wrote into a freshly built `model` and its `venv` (the same recipe):
    `torch.load(..., weights_only=True)` and `np.load(..., allow_pickle=False)` only, every failure one
    sentence."""
    import torch

    def broken(why: str) -> UserError:
        return UserError(f"training checkpoint {ckpt} {why}; restore it or start the expert again without --resume.")

    payload = load_weights(ckpt, "training checkpoint", device)  # weights_only: a hostile pickle runs nothing
    if not isinstance(payload, dict) or payload.get("format") != CHECKPOINT_FORMAT:
        raise broken("is not a digail expert checkpoint")
    algo = "sac" if getattr(model, "replay_buffer", None) is not None else "ppo"
    if payload.get("algo") != algo:
        raise broken(f"was written by {payload.get('algo')!r}, not by this recipe's {algo!r}")
    try:
        model.set_parameters(payload["params"], exact_match=True, device=device)
        ent = getattr(model, "log_ent_coef", None)
        if isinstance(ent, torch.Tensor) and payload.get("log_ent_coef") is not None:
            with torch.no_grad():
                ent.copy_(payload["log_ent_coef"])  # in place: the entropy optimiser holds this tensor
        model.num_timesteps = int(payload["num_timesteps"])
        model._n_updates = int(payload["n_updates"])
        model._episode_num = int(payload["episode_num"])
    except (KeyError, TypeError, ValueError, RuntimeError) as exc:
        raise broken(f"does not fit this recipe's networks ({type(exc).__name__})") from None
    stats, replay = _companions(ckpt)
    if hasattr(venv, "obs_rms"):
        z = _read_npz(stats, "normaliser statistics")
        try:
            for rms, key in ((venv.obs_rms, "obs"), (venv.ret_rms, "ret")):
                mean, var = np.asarray(z[f"{key}_mean"], np.float64), np.asarray(z[f"{key}_var"], np.float64)
                if mean.shape != np.shape(rms.mean) or var.shape != np.shape(rms.var):
                    raise ValueError(f"{key} statistics of shape {mean.shape}")
                rms.mean, rms.var, rms.count = mean, var, float(z[f"{key}_count"])
        except (KeyError, ValueError, TypeError) as exc:
            raise UserError(f"the normaliser statistics {stats} do not fit this env ({one_line(exc)}); restore "
                            "them or start the expert again without --resume.") from None
    buffer = getattr(model, "replay_buffer", None)
    if buffer is not None and replay.is_file():  # without it, training resumes with an empty buffer
        z = _read_npz(replay, "replay buffer")
        try:
            filled = 0
            for k in REPLAY_ARRAYS:
                dst = getattr(buffer, k, None)
                if dst is None:
                    continue
                src = z[k]
                if src.shape[1:] != dst.shape[1:] or len(src) > len(dst):
                    raise ValueError(f"{k} of shape {src.shape}")
                dst[:len(src)] = src
                filled = len(src)
            buffer.pos, buffer.full = int(z["pos"]), bool(z["full"])
            if buffer.pos > filled or buffer.pos >= buffer.buffer_size:
                raise ValueError(f"position {buffer.pos}")
        except (KeyError, ValueError, TypeError) as exc:
            raise UserError(f"the replay buffer {replay} does not fit this recipe ({one_line(exc)}); restore it or "
                            "start the expert again without --resume.") from None


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


def build_sb3_model(env_id: str, spec: ExpertSpec, seed: int, device: str) -> tuple[Any, Any]:
    """A fresh SB3 model for `spec` and its env: PPO on a `VecNormalize`, or SAC on the raw vec env."""
    from stable_baselines3 import PPO, SAC
    from stable_baselines3.common.vec_env import VecNormalize

    if spec.algo == "sac":
        venv = _make_vec_env(env_id, spec, seed)
        sac_kwargs = {"net_arch": list(spec.net_arch), "activation_fn": ACTIVATIONS[spec.activation]}
        sac = SAC("MlpPolicy", venv, gamma=spec.gamma, policy_kwargs=sac_kwargs, seed=seed, device=device,
                  verbose=0, **spec.sac)
        return sac, venv
    venv = VecNormalize(_make_vec_env(env_id, spec, seed), norm_obs=True, norm_reward=spec.norm_reward,
                        gamma=spec.gamma)
    kwargs = dict(spec.ppo)
    kwargs["learning_rate"] = _learning_rate(kwargs.get("learning_rate", 3e-4))
    policy_kwargs = {
        "net_arch": {"pi": list(spec.net_arch), "vf": list(spec.net_arch)},
        "activation_fn": ACTIVATIONS[spec.activation],
        "log_std_init": spec.log_std_init,
    }
    model = PPO("MlpPolicy", venv, gamma=spec.gamma, use_sde=spec.use_sde, policy_kwargs=policy_kwargs,
                seed=seed, device=device, verbose=0, **kwargs)
    return model, venv


def _load_model(env_id: str, spec: ExpertSpec, ckpt: Path, seed: int, device: str) -> tuple[Any, Any]:
    """The recipe's model rebuilt fresh, then given the checkpoint's weights, statistics and buffer."""
    model, venv = build_sb3_model(env_id, spec, seed, device)
    load_checkpoint(model, venv, ckpt, device)
    return model, venv


def _progress_callback(total: int, spec: ExpertSpec, env_id: str, out: Path, seed: int,
                       t_start: float) -> Any:
    """SB3 callback: progress bar, resumable checkpoints, periodic evaluation, best export, early stop."""
    from stable_baselines3.common.callbacks import BaseCallback

    class _Callback(BaseCallback):
        def __init__(self) -> None:
            super().__init__()
            self.bar: Any = None
            self.next_ckpt = 0
            self.next_eval = 0
            self.history: list[dict[str, Any]] = []

        def _on_training_start(self) -> None:
            done = self.num_timesteps
            self.bar = progress_bar(total, desc=env_id, unit="step", initial=done)
            self.next_ckpt = (done // spec.checkpoint_every + 1) * spec.checkpoint_every
            self.next_eval = (done // spec.eval_every + 1) * spec.eval_every
            self.history = read_progress(out, warn=False).get("evals", [])

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
            save_checkpoint(self.model, self.training_env, ckpt_dir / f"step_{self.num_timesteps}")
            self._save_progress()
            for _, old in _checkpoints(ckpt_dir)[:-2]:  # keep the last two
                old.unlink(missing_ok=True)
                for companion in _companions(old):
                    companion.unlink(missing_ok=True)

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
    """environment id with an RL expert recipe (`digail.experts.recipes.RECIPES`)"""
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


def read_progress(out: Path, warn: bool = True) -> dict[str, Any]:
    """An expert folder's `progress.json` (its periodic evaluations); empty when it is missing, and empty with a
    warning when it is damaged: the checkpoints alone resume the training, only the evaluation history is lost."""
    path = out / "progress.json"
    if not path.exists():
        return {}
    try:
        progress = json.loads(path.read_text())
        if isinstance(progress, dict):
            return progress
    except (OSError, ValueError):
        pass
    if warn:
        print(f"digail expert: warning: {path} is damaged; resuming from the checkpoints without its evaluation "
              "history.", file=sys.stderr)
    return {}


def train_expert(args: ExpertRun) -> Path:
    """Train (or resume) a PPO or SAC expert, then evaluate it on 50 fresh episodes.

    Writes into OUT: `checkpoints/` (resumable SB3 checkpoints), `expert.pt` / `best_expert.pt` (exported
    actors), `progress.json` (periodic evaluations) and `eval.json` (final 50-episode evaluation of
    `best_expert.pt`, deterministic actions). Returns OUT.
    """
    spec = spec_for(args.env)
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
            old = " (its step_*.zip checkpoints are of an older, pickle-based format that is no longer loaded)" \
                if ckpt_dir.is_dir() and any(ckpt_dir.glob("step_*.zip")) else ""
            raise UserError(f"nothing to resume in {out}: no checkpoints/step_*.pt{old}; drop --resume to start "
                            "anew.")
        progress = read_progress(out)
        if progress.get("env_id", args.env) != args.env:
            raise UserError(f"{out} holds an expert for {progress['env_id']!r}, not {args.env!r}; "
                            "resume with the same env or choose another --out.")
    elif existing or (out / "expert.pt").exists() or (ckpt_dir.is_dir() and any(ckpt_dir.glob("step_*.zip"))):
        raise UserError(f"{out} already holds a training run; pass --resume to continue it or choose "
                        "another --out.")
    else:  # a new folder, or one digail made: never a user's folder, a file, a link or a device
        if out.is_dir() and not out.is_symlink() and not digail_made(out):
            raise UserError(f"{out} is a folder digail did not make; `digail expert` writes only into a new folder "
                            "or one of its own, choose another --out.")
        check_output(out, "folder", force=True, writes="`digail expert` writes a folder")
    out.mkdir(parents=True, exist_ok=True)
    write_marker(out)
    with run_dir_lock(out):  # one writer per expert folder: a second `digail expert` on it is refused
        return _train_in(args, spec, out, total, device, existing[-1][1] if args.resume else None)


def _train_in(args: ExpertRun, spec: ExpertSpec, out: Path, total: int, device: str, ckpt: Path | None) -> Path:
    """`train_expert` in its checked and held folder, from the checkpoint `ckpt` or from scratch."""
    if ckpt is not None:
        model, _ = _load_model(args.env, spec, ckpt, args.seed, device)
        progress = read_progress(out, warn=False)  # warned once already, by the checks before
        (out / "wall_before_resume.txt").write_text(str(progress.get("wall_s", 0.0)))
    else:
        (out / "wall_before_resume.txt").unlink(missing_ok=True)
        model, _ = build_sb3_model(args.env, spec, args.seed, device)
    # the one run-folder schema (`kind` "expert"), with the budget and the recipe it trained with
    write_run_config(out, run_config(kind="expert", env_id=args.env, demos=None, seed=args.seed, device=device,
                                     args=args, steps=total, expert=to_dict(spec)))
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
