"""Directed-Info GAIL (Sharma et al., ICLR 2019, section 3 and eq. 4), and the `digail train` command.

Extends GAIL with K sub-task codes: the macro-policy q(c_t | s_t, c_{t-1}) from VAE pre-training is frozen and
picks codes during rollouts (closed-loop on the agent's own states, or replaying q's segmentation of a random
expert demonstration), and the reward gains the directed-information bonus lambda_1 * log q(c_t | s_t, c_{t-1}).
"""

from __future__ import annotations

import json
from dataclasses import replace
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np
import torch

from digail.algos.gail import GAIL
from digail.config import TrainConfig, from_dict, to_dict
from digail.data.trajectory import Trajectory
from digail.errors import UserError
from digail.nets.fast import CodeMLP, log_softmax
from digail.nets.vae import HierarchicalPolicy

if TYPE_CHECKING:
    from digail.cli import TrainArgs


class DirectedInfoGAIL(GAIL):
    """GAIL on pi(a | s, c) with codes from a frozen macro-policy q and the directed-info bonus.

    Sign of the bonus: paper eq. 4 minimises `-lambda_1 L_1` with `L_1 = sum_t E[log q(c_t | c_{<t}, tau_{1:t})]`
    (the variational lower bound of the directed information I(tau -> c)), i.e. the policy *maximises*
    lambda_1 * log q. As a reward, log q(c_t | s_t, c_{t-1}) scores the state s_t, so it is credited to the
    transition (s_{t-1}, a_{t-1}) that produced s_t. The authors' released code subtracted it; we do not.

    Code sources per env (DESIGN.md): the first `round(replay_fraction * N)` envs replay q's causal segmentation
    of a random expert demonstration (samples of p(c^{1:t})), continued closed-loop past its end; the others
    sample c_t ~ q(. | s_t, c_{t-1}) on their own states.
    """

    method = "digail"

    def __init__(self, *args, **kwargs) -> None:  # type: ignore[no-untyped-def]
        super().__init__(*args, **kwargs)
        self.n_replay = int(round(self.cfg.replay_fraction * self.envs.num_envs))
        # q's segmentations with a column of -1 (past a demonstration's end) and a row of -1 (the replay index of
        # closed-loop envs): a code is replayed where the table holds one, with no further checks per step
        length = self.replay_codes.shape[1]
        self._replay_table = np.full((len(self.replay_codes) + 1, length + 1), -1, dtype=np.int64)
        self._replay_table[:-1, :length] = self.replay_codes

    def _start_episodes(self, idx: np.ndarray) -> None:
        super()._start_episodes(idx)
        demo = self.np_rng.integers(len(self.replay_codes), size=len(idx))
        self.codes_state.replay_idx[idx] = np.where(idx < self.n_replay, demo, -1)

    def _is_closed_loop(self, i: int) -> bool:
        return i >= self.n_replay

    def _choose_codes(self, obs_n: np.ndarray, prev: np.ndarray, t_ep: np.ndarray,
                      env_idx: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """c_t and log q(c_t | s_t, c_{t-1}) for the envs `env_idx`; obs_n, prev and t_ep are aligned with it.

        The rollout hot path, so it runs in NumPy: q from its weight snapshot (the rollout's, else a fresh one),
        which takes prev as integers, and the Gumbel noise of sampled codes from `np_rng`.
        """
        snap = self._q_snap if self._q_snap is not None else CodeMLP([self.model.q.net], self.model.obs_dim)
        logp_all = log_softmax(snap(obs_n, prev))
        if self.cfg.closed_loop_codes == "argmax":
            codes = logp_all.argmax(-1)
        else:
            codes = (logp_all + self.np_rng.gumbel(size=logp_all.shape)).argmax(-1)  # a sample of q (Gumbel-max)
        if self.n_replay:
            table = self._replay_table
            replayed = table[self.codes_state.replay_idx[env_idx], np.minimum(t_ep, table.shape[1] - 1)]
            codes = np.where(replayed >= 0, replayed, codes)
        logq = logp_all[np.arange(len(codes)), codes]
        return codes, logq


# -------------------------------------------------------------------------------------------- the command
def build_trainer(env_id: str, demos: list[Trajectory], cfg: TrainConfig, *, vae_model: HierarchicalPolicy | None,
                  seed: int, run_dir: Path | None, device: str | torch.device = "cpu",
                  progress: bool = True) -> GAIL:
    """The trainer for `cfg.method` with its policy initialised as configured.

    digail needs the pre-trained VAE (its q and normaliser; its decoder initialises pi when `init_from_vae`).
    gail uses one code and a fresh policy; the normaliser is fitted on the demonstrations.
    """
    from digail.nets.policy import ActionSpec

    if cfg.method == "digail":
        if vae_model is None:
            raise UserError("Directed-Info GAIL needs a pre-trained VAE; pass --vae RUN "
                            "(make one with `digail pretrain --demos D`).")
        model = vae_model
        if not cfg.init_from_vae:
            fresh = HierarchicalPolicy(model.obs_dim, model.codes, model.action, cfg.hidden, pi_obs=model.pi_obs)
            model.pi.load_state_dict(fresh.pi.state_dict())
        return DirectedInfoGAIL(env_id, demos, model, cfg, seed=seed, run_dir=run_dir, device=device,
                                progress=progress)
    obs_dim = int(np.asarray(demos[0].obs).reshape(len(demos[0].obs), -1).shape[1])
    from digail.algos.rollout import make_env

    probe = make_env(env_id)
    action = ActionSpec.from_space(probe.action_space)
    probe.close()
    model = HierarchicalPolicy(obs_dim, 1, action, cfg.hidden)
    model.normalizer.fit(np.concatenate([np.asarray(t.obs) for t in demos]))
    return GAIL(env_id, demos, model, cfg, seed=seed, run_dir=run_dir, device=device, progress=progress)


def train_command(args: TrainArgs) -> Path:
    """`digail train`: validate everything, then train (or resume) in a run folder."""
    from digail.cli import TrainArgs
    from digail.utils import check_new_dir, default_run_dir, resolve_device, set_torch_threads, write_json

    set_torch_threads(1)
    if args.resume is not None:
        run_dir = Path(args.resume)
        cfg_path = run_dir / "config.json"
        if not cfg_path.exists():
            raise UserError(f"{run_dir} is not a training run folder (no config.json); pass the folder "
                            "`digail train` created.")
        saved = json.loads(cfg_path.read_text())
        args = from_dict(TrainArgs, saved["args"])
        args = replace(args, out=run_dir, resume=run_dir, force=True)
    device = resolve_device(args.device)
    demos, env_id = _load_demos_for(args)
    cfg = args.train
    cfg = replace(cfg, method=args.method)
    if args.bc_weight is not None:
        cfg = replace(cfg, bc_weight=args.bc_weight)
    vae_model = None
    if args.vae is not None:
        from digail.checkpoint import load_model

        vae_model, meta = load_model(Path(args.vae) / "model.pt")
        if meta.get("env_id") not in (None, env_id):
            raise UserError(f"the VAE in {args.vae} was trained on {meta.get('env_id')}, not {env_id}; "
                            "pre-train one on this env's demonstrations.")
        if vae_model.obs_dim != int(np.asarray(demos[0].obs).reshape(len(demos[0].obs), -1).shape[1]):
            raise UserError(f"the VAE in {args.vae} expects {vae_model.obs_dim}-d observations but the "
                            "demonstrations have another size; pre-train it on these demonstrations.")
    run_dir = Path(args.out) if args.out is not None else default_run_dir(env_id, cfg.method, args.seed)
    if args.resume is None:
        check_new_dir(run_dir, args.force)
    trainer = build_trainer(env_id, demos, cfg, vae_model=vae_model, seed=args.seed, run_dir=None,
                            device=device)
    ckpt = run_dir / "checkpoint.pt"
    if args.resume is not None:
        if not ckpt.exists():
            raise UserError(f"no checkpoint in {run_dir}; it was killed before the first one - start it again.")
        trainer.load_checkpoint(ckpt)
        print(f"resuming {run_dir} at iteration {trainer.iteration}/{cfg.iterations}")
    else:
        run_dir.mkdir(parents=True, exist_ok=True)
        resolved = replace(args, train=cfg, env=env_id)
        write_json(run_dir / "config.json", {"args": to_dict(resolved), "method": cfg.method, "env_id": env_id,
                                             "demos": args.demos, "seed": args.seed})
    trainer.run_dir = run_dir
    trainer.train(evaluate=_periodic_evaluation(env_id, cfg))
    trainer.save_checkpoint(ckpt)
    return run_dir


def _periodic_evaluation(env_id: str, cfg: TrainConfig):  # type: ignore[no-untyped-def]
    """The `evaluate` hook of `GAIL.train` for `cfg.eval_every` > 0: deterministic closed-loop episodes from the
    final evaluation's seeds, normalised by the expert measured once on the same seeds (None when disabled)."""
    if cfg.eval_every <= 0:
        return None
    from digail.eval.returns import evaluate, expert_summary

    seed = 10_000
    expert = expert_summary(env_id, cfg.eval_episodes, seed)
    denom = expert["mean_return"] if expert is not None else 0.0

    def hook(model: HierarchicalPolicy) -> dict[str, float]:
        result = evaluate(model, env_id, cfg.eval_episodes, seed, deterministic=True, with_expert=False)
        out = {k: float(v) for k, v in result.items()
               if isinstance(v, float) and k not in ("std_return",) and np.isfinite(v)}
        if abs(denom) > 1e-6:
            out["normalized_return"] = out["mean_return"] / denom
        return out

    return hook


def _load_demos_for(args: TrainArgs) -> tuple[list[Trajectory], str]:
    from digail.data.minari_io import check_matches_env, load_dataset

    if not args.demos:
        raise UserError("no demonstrations given; pass --demos with a Minari dataset folder or id.")
    ds = load_dataset(args.demos)
    env_id = args.env or ds.env_id
    if not env_id:
        raise UserError(f"the dataset {args.demos} does not name its environment; pass --env.")
    check_matches_env(ds, env_id)
    return list(ds.trajs), env_id
