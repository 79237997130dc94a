"""Does each piece of the fast path (`digail.algos.fast`) still pay? Fast against reference, side by side, rounds
interleaved in one process, medians of per-round ratios.

    python benchmarks/studies/fast_path.py [--rounds 5] [--out runs/bench/fast_path.json]

- `ppo_update`: 10 epochs on random batches of Circle-World's size (512 rows, minibatch 128) and Hopper's (4096,
  512): the fast path against the reference;
- `vae`: ELBO pre-training (`--vae.init none`, batch 16) on the shipped Circle-World (20 epochs) and Four Rooms
  (4 epochs) demonstrations, `FusedVAEStep` against autograd;
- `gumbel_chain`: the Gumbel-softmax chain's forward and backward pass on a Circle-World batch (16 demonstrations
  of 120 steps, K = 2) and a Four Rooms one (16, 64 steps, K = 4), straight-through samples (`--vae.hard`: the
  scripted sampling loop) and `--vae.bptt` (the hand-written backward pass), against q's module step by step;
- `polish`: 1000 polish steps (`fit_to_codes`, minibatch 256) on the shipped Circle-World and Four Rooms
  demonstrations, the scripted loss-and-gradient step against autograd through the modules;
- `rollout`: Directed-Info GAIL rollouts (`PPOLearner.collect`, 16 envs x 128 steps, sync) on Circle-World and Four
  Rooms, the NumPy snapshots against the modules' torch forward passes;
- `iteration`: whole training iterations (`GAIL.iterate`: rollout, D, reward, update) with each env's preset
  (sync envs), GAIL with a fresh policy: PPO on Circle-World and Hopper as `fast` (every piece on, PPO's
  hand-written gradient), `compiled` (every piece on but PPO's loss through `torch.compile` instead of the hand
  gradient), `reference+compile` (the reference path, the loss compiled) and `reference`; SAC on Hopper
  (`--train.sac.steps-per-iteration 200`, after 1000 steps of warm-up) as `fast` against `reference` (SAC has no
  compiled path);
- `pieces`: the same iterations with one piece of the fast path off at a time (the rest on): `-inference` (the
  rollout's pi, V and q through their modules), `-hand grad` (PPO's loss through autograd, eager), `compiled`
  (PPO's loss through `torch.compile`, what the MuJoCo presets run), and for SAC `-sac hand` (SAC's update through
  autograd) and `-d hand` (D's step through autograd); each against `fast`.
"""

from __future__ import annotations

import argparse
import contextlib
import json
import statistics
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import torch

from digail.algos import fast
from digail.algos.batch import PPOBatch
from digail.algos.optim import adam
from digail.algos.ppo import ppo_update
from digail.algos.vae_pretrain import pretrain
from digail.config import PPOConfig, VAEConfig
from digail.data.minari_io import load_dataset
from digail.nets.critic import ValueNet
from digail.nets.policy import ActionSpec, SubtaskPolicy
from digail.utils import set_torch_threads


def _interleaved(fns: dict[str, Callable[[], Any]], rounds: int) -> dict[str, list[float]]:
    times: dict[str, list[float]] = {name: [] for name in fns}
    for r in range(rounds):
        for name in (list(fns) if r % 2 == 0 else list(fns)[::-1]):
            t = time.perf_counter()
            fns[name]()
            times[name].append(time.perf_counter() - t)
    return times


def _summary(times: dict[str, list[float]], base: str) -> dict[str, Any]:
    out: dict[str, Any] = {"median_s": {k: round(statistics.median(v), 4) for k, v in times.items()}}
    for name, v in times.items():
        if name != base:
            ratios = [a / b for a, b in zip(v, times[base], strict=True)]
            out[f"{name}_over_{base}"] = round(statistics.median(ratios), 3)
    return out


def ppo_study(rounds: int) -> dict[str, Any]:
    def update(obs: int, codes: int, act: int, n: int, mb: int, mode: str) -> None:
        torch.manual_seed(0)
        pi, v = SubtaskPolicy(obs, codes, ActionSpec(False, act)), ValueNet(obs, codes)
        g = torch.Generator().manual_seed(1)
        o, c = torch.randn(n, obs, generator=g), torch.eye(codes)[torch.randint(codes, (n,), generator=g)]
        with torch.no_grad():
            d = pi.dist(o, c)
            a = d.sample()
            batch = PPOBatch(o, c, a, d.log_prob(a), torch.randn(n, generator=g), torch.randn(n, generator=g))
        opt = adam([*pi.parameters(), *v.parameters()], 3e-4)
        cfg = PPOConfig(batch_size=n, minibatch_size=mb, epochs=10)
        with fast.pinned(mode == "fast"):
            ppo_update(pi, v, opt, batch, cfg, torch.Generator().manual_seed(0))

    out = {}
    for name, size in {"circle-world (512 rows, minibatch 128)": (2, 2, 2, 512, 128),
                       "hopper (4096 rows, minibatch 512)": (11, 4, 3, 4096, 512)}.items():
        update(*size, "fast")  # TorchScript compiles once
        fns = {mode: (lambda mode=mode, size=size: update(*size, mode))
               for mode in ("fast", "reference")}
        out[name] = _summary(_interleaved(fns, rounds), "fast")
    return out


def vae_study(rounds: int) -> dict[str, Any]:
    out = {}
    for dataset, codes, epochs in (("digail/circleworld/expert-v0", 2, 20), ("digail/fourrooms/expert-v0", 4, 4)):
        trajs = load_dataset(dataset).trajs
        cfg = VAEConfig(codes=codes, epochs=epochs, batch_size=16, init="none", tau_decay=3e-3)
        pretrain(trajs, cfg, seed=0, progress=False)  # TorchScript compiles once

        def reference(trajs: Any = trajs, cfg: VAEConfig = cfg) -> None:
            with fast.reference():
                pretrain(trajs, cfg, seed=0, progress=False)

        fns = {"fast": lambda trajs=trajs, cfg=cfg: pretrain(trajs, cfg, seed=0, progress=False),
               "reference": reference}
        out[f"{dataset} ({epochs} epochs)"] = _summary(_interleaved(fns, rounds), "fast")
    return out


def chain_study(rounds: int) -> dict[str, Any]:
    from digail.algos.gumbel import gumbel_softmax_chain
    from digail.nets.vae import MacroPolicy

    out = {}
    for name, (obs_dim, codes, steps) in {"circle-world (16 x 120, K 2)": (2, 2, 120),
                                          "four-rooms (16 x 64, K 4)": (6, 4, 64)}.items():
        for flag in ("hard", "bptt"):
            torch.manual_seed(0)
            q = MacroPolicy(obs_dim, codes)
            obs_n = torch.randn(16, steps, obs_dim)

            def run(q: MacroPolicy = q, obs_n: torch.Tensor = obs_n, flag: str = flag) -> None:
                for i in range(20):
                    logits, c = gumbel_softmax_chain(q, obs_n, 0.5, flag == "hard", torch.Generator().manual_seed(i),
                                                     bptt=flag == "bptt")
                    (logits.sum() + (c * c).sum()).backward()

            def reference(run: Callable[[], None] = run) -> None:
                with fast.reference():
                    run()

            run()  # TorchScript compiles once
            out[f"{name}, --vae.{flag}, 20 batches"] = _summary(_interleaved({"fast": run, "reference": reference},
                                                                             rounds), "fast")
    return out


def _demo_codes(trajs: Any, codes: int) -> list[Any]:
    """A segmentation to fit to (the speed does not depend on which): each demonstration cut into equal parts."""
    import numpy as np

    return [np.minimum(np.arange(len(t)) * codes // len(t), codes - 1) for t in trajs]


def polish_study(rounds: int) -> dict[str, Any]:
    from digail.algos.polish import fit_to_codes
    from digail.data.validation import check_demos
    from digail.nets.vae import HierarchicalPolicy

    out = {}
    for dataset, codes in (("digail/circleworld/expert-v0", 2), ("digail/fourrooms/expert-v0", 4)):
        trajs = load_dataset(dataset).trajs
        obs_dim, spec = check_demos(trajs, None)
        segs = _demo_codes(trajs, codes)

        def run(trajs: Any = trajs, obs_dim: int = obs_dim, spec: Any = spec, segs: Any = segs,
                codes: int = codes) -> None:
            import numpy as np

            torch.manual_seed(0)
            model = HierarchicalPolicy(obs_dim, codes, spec)
            model.normalizer.fit(np.concatenate([np.asarray(t.obs, np.float64).reshape(len(t.obs), -1)
                                                 for t in trajs]))
            fit_to_codes(model, trajs, segs, 1000, 3e-3, q_noise=0.1, seed=0, progress=False)

        def reference(run: Callable[[], None] = run) -> None:
            with fast.reference():
                run()

        run()  # TorchScript compiles once
        out[f"{dataset} (1000 steps)"] = _summary(_interleaved({"fast": run, "reference": reference}, rounds),
                                                  "fast")
    return out


def rollout_study(rounds: int) -> dict[str, Any]:
    from digail.algos.directed_info_gail import DirectedInfoGAIL
    from digail.config import TrainConfig
    from digail.data.validation import check_demos
    from digail.nets.vae import HierarchicalPolicy

    out = {}
    for dataset, env_id, codes in (("digail/circleworld/expert-v0", "digail/CircleWorld-v0", 2),
                                   ("digail/fourrooms/expert-v0", "digail/FourRooms-v0", 4)):
        trajs = load_dataset(dataset).trajs
        obs_dim, spec = check_demos(trajs, None)
        torch.manual_seed(0)
        model = HierarchicalPolicy(obs_dim, codes, spec)
        cfg = TrainConfig(ppo=PPOConfig(num_envs=16, batch_size=16 * 128, minibatch_size=256), backend="sync")
        trainer = DirectedInfoGAIL(env_id, list(trajs), model, cfg, seed=0, progress=False)

        def run(trainer: Any = trainer) -> None:
            for _ in range(3):
                trainer.learner.collect()

        def reference(run: Callable[[], None] = run) -> None:
            with fast.reference():
                run()

        run()
        out[f"{env_id} (3 rollouts of 16 envs x 128 steps)"] = _summary(
            _interleaved({"fast": run, "reference": reference}, rounds), "fast")
        trainer.close()
    return out


def iteration_study(rounds: int) -> dict[str, Any]:
    import dataclasses

    from digail.algos.directed_info_gail import build_trainer
    from digail.commands.train import load_demos
    from digail.data.demos import default_dataset_id
    from digail.envs.registry import preset_for

    def trainer(env_id: str, learner: str, *, compile_: bool, reference: bool) -> Any:
        base = preset_for(env_id).train
        cfg = dataclasses.replace(base, method="gail", learner=learner, backend="sync", value_warmup=0,
                                  ppo=dataclasses.replace(base.ppo, compile=compile_),
                                  sac=dataclasses.replace(base.sac, steps_per_iteration=200, learning_starts=1000,
                                                          policy_warmup=0))
        demos, _ = load_demos(default_dataset_id(env_id), env_id)
        with fast.reference() if reference else _nothing():
            tr = build_trainer(env_id, demos, cfg, vae_model=None, seed=0, run_dir=None, progress=False)
            for _ in range(2 if learner == "ppo" else 6):  # first resets, allocations, compiles; SAC's buffer
                tr.iterate()
        return tr

    def timed(tr: Any, reference: bool) -> Callable[[], None]:
        def run() -> None:
            with fast.reference() if reference else _nothing():
                tr.iterate()
        return run

    out: dict[str, Any] = {}
    cases = {("digail/CircleWorld-v0", "ppo"): {"fast": (False, False), "compiled": (True, False),
                                               "reference+compile": (True, True), "reference": (False, True)},
             ("Hopper-v5", "ppo"): {"fast": (False, False), "compiled": (True, False),
                                    "reference+compile": (True, True), "reference": (False, True)},
             ("Hopper-v5", "sac"): {"fast": (False, False), "reference": (False, True)}}
    for (env_id, learner), variants in cases.items():
        if MATCH not in f"{env_id} {learner}":
            continue
        trainers = {name: trainer(env_id, learner, compile_=c, reference=r) for name, (c, r) in variants.items()}
        fns = {name: timed(trainers[name], variants[name][1]) for name in variants}
        out[f"{env_id} {learner} (one iteration)"] = _summary(_interleaved(fns, rounds), "fast")
        print(env_id, learner, out[f"{env_id} {learner} (one iteration)"], flush=True)
        for tr in trainers.values():
            tr.close()
    return out


MATCH = ""
"""`--match`: the `iteration` and `pieces` studies run only the cases whose "env learner" contains it"""
PIECES: list[str] = []
"""`--pieces`: the `pieces` study runs only these variants (and `fast`), named without their minus; all when
empty"""


def pieces_study(rounds: int) -> dict[str, Any]:
    import dataclasses
    from unittest import mock

    from digail.algos import inference
    from digail.algos.directed_info_gail import build_trainer
    from digail.commands.train import load_demos
    from digail.data.demos import default_dataset_id
    from digail.envs.registry import preset_for

    def build(env_id: str, learner: str, compile_: bool = False) -> Any:
        base = preset_for(env_id).train
        cfg = dataclasses.replace(base, method="gail", learner=learner, backend="sync", value_warmup=0,
                                  ppo=dataclasses.replace(base.ppo, compile=compile_),
                                  sac=dataclasses.replace(base.sac, steps_per_iteration=200, learning_starts=200,
                                                          policy_warmup=0))
        demos, _ = load_demos(default_dataset_id(env_id), env_id)
        return build_trainer(env_id, demos, cfg, vae_model=None, seed=0, run_dir=None, progress=False)

    def without(piece: str, tr: Any) -> contextlib.AbstractContextManager[Any]:
        if piece == "-inference":
            stack = contextlib.ExitStack()
            stack.enter_context(mock.patch.object(inference, "actor_critic",
                                                  lambda pi, v, d: inference.ModuleActorCritic(pi, v)))
            stack.enter_context(mock.patch.object(inference, "code_net", lambda q, d: inference.ModuleCodeNet(q)))
            return stack
        if piece == "-hand grad":
            return mock.patch("digail.algos.ppo.HAND_GRAD_MAX_ROWS", 0)
        if piece == "-sac hand":
            tr.learner.sac.hand = False
        if piece == "-d hand":
            tr.reward.penalty_step.hand = False
        return _nothing()

    out: dict[str, Any] = {}
    cases = {("digail/CircleWorld-v0", "ppo"): ["fast", "-inference", "-hand grad", "compiled"],
             ("Hopper-v5", "ppo"): ["fast", "-inference", "-hand grad", "compiled"],
             ("Hopper-v5", "sac"): ["fast", "-sac hand", "-d hand"]}
    for (env_id, learner), variants in cases.items():
        if MATCH not in f"{env_id} {learner}":
            continue
        variants = [v for v in variants if v == "fast" or not PIECES or v.lstrip("-") in PIECES]
        trainers = {name: build(env_id, learner, compile_=name == "compiled") for name in variants}
        fns = {}
        for name, tr in trainers.items():
            def run(tr: Any = tr, name: str = name) -> None:
                with without(name, tr):
                    tr.iterate()
            run()
            run()  # first resets, allocations; SAC's buffer reaches learning_starts
            fns[name] = run
        key = f"{env_id} {learner} (one iteration, one piece off)"
        out[key] = _summary(_interleaved(fns, rounds), "fast")
        print(key, out[key], flush=True)
        for tr in trainers.values():
            tr.close()
    return out


@contextlib.contextmanager
def _nothing() -> Any:
    yield


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--rounds", type=int, default=5)
    parser.add_argument("--only", nargs="*",
                        default=["ppo_update", "vae", "gumbel_chain", "polish", "rollout", "iteration",
                                 "pieces"])
    parser.add_argument("--out", default="runs/bench/fast_path.json")
    parser.add_argument("--pieces", nargs="*", default=[], help="pieces: only these variants besides fast "
                        "(inference, 'hand grad', compiled, 'sac hand', 'd hand')")
    parser.add_argument("--match", default="", help="iteration, pieces: only the cases whose 'env learner' "
                        "contains this")
    args = parser.parse_args()
    global MATCH, PIECES
    MATCH, PIECES = args.match, args.pieces
    set_torch_threads(1)
    studies = {"ppo_update": ppo_study, "vae": vae_study, "gumbel_chain": chain_study,
               "polish": polish_study, "rollout": rollout_study,
               "iteration": iteration_study, "pieces": pieces_study}
    results = {name: studies[name](args.rounds) for name in args.only}
    Path(args.out).parent.mkdir(parents=True, exist_ok=True)
    Path(args.out).write_text(json.dumps(results, indent=2) + "\n")
    print(json.dumps(results, indent=2))


if __name__ == "__main__":
    main()
