"""Training an expert with Stable-Baselines3: the model, resumable checkpoints, periodic evaluations, the export."""

from __future__ import annotations

import json
import math
import re
import shutil
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from digail.checkpoint import run_config, write_run_config
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
from digail.utils import resolve_device, set_torch_threads, write_json

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


def _load_model(env_id: str, spec: ExpertSpec, zip_path: Path, seed: int, device: str) -> tuple[Any, Any]:
    from stable_baselines3 import PPO, SAC
    from stable_baselines3.common.vec_env import VecNormalize

    if spec.algo == "sac":
        venv = _make_vec_env(env_id, spec, seed)
        sac = SAC.load(str(zip_path), env=venv, device=device)
        replay = zip_path.with_suffix(".replay.pkl")
        if replay.is_file():  # without it, training resumes with an empty buffer
            sac.load_replay_buffer(str(replay))
        return sac, venv
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
            model: Any = self.model
            model.save(str(stem) + ".zip")
            if spec.algo == "sac":
                model.save_replay_buffer(str(stem) + ".replay.pkl")
            else:
                vec_normalize: Any = self.training_env  # a VecNormalize, which adds save()
                vec_normalize.save(str(stem) + ".vecnormalize.pkl")
            self._save_progress()
            for _, old in _checkpoints(ckpt_dir)[:-2]:  # keep the last two
                old.unlink(missing_ok=True)
                old.with_suffix(".vecnormalize.pkl").unlink(missing_ok=True)
                old.with_suffix(".replay.pkl").unlink(missing_ok=True)

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
