"""The hard-EM start on one task of the segmentation benchmark, without the VAE: what a ridge or a sub-task model
does to it, and whether its criterion ranks the oracle labels above what it finds.

    python benchmarks/studies/segmentation_start.py curved --ridges 1.0 0.02
        the start's accuracy and switches per episode for each ridge (`segment_init.hard_em_segmentation`)
    python benchmarks/studies/segmentation_start.py fetch --ridges 0.01 --oracle
        also the description length (nats) of the oracle labels, of hard EM started from them and of what the
        start finds, under that ridge (`segment_init.hard_em_from`; lower is preferred by the criterion)
    python benchmarks/studies/segmentation_start.py four-rooms --ridges 0.003 --starts 16 --seeds 0 1
        the same with more k-means starts, from two seeds
    python benchmarks/studies/segmentation_start.py circle-world --curve rff --ridges 0.01 --seeds 0 1
        the K curve (K = 2 .. 8, held-out description length per step) and the K chosen, as `--codes auto`
        computes it but with this model and ridge (`segment_init.heldout_codes_curve`); `--previous-action`
        lets every sub-task policy also see the action before (the first step: its own)
    python benchmarks/studies/segmentation_start.py circle-world --residuals
        the residual of each sub-task model fitted to the oracle labels (Circle-World: how well one code can
        describe one circle)

Tasks and data are those of `benchmarks/segmentation.py` (recorded or written into `--data` once). One torch thread.
"""

from __future__ import annotations

import argparse
import dataclasses
import importlib.util
import sys
import time
from pathlib import Path
from types import ModuleType

import numpy as np

from digail.data.trajectory import Trajectory


def _benchmark(name: str) -> ModuleType:
    """benchmarks/<name>.py, loaded from its file once (this study lives one folder below it)."""
    if name in sys.modules:
        return sys.modules[name]
    spec = importlib.util.spec_from_file_location(name, Path(__file__).resolve().parents[1] / f"{name}.py")
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    sys.modules[name] = module
    spec.loader.exec_module(module)
    return module


segmentation = _benchmark("segmentation")
task_data, task_names = segmentation.task_data, segmentation.task_names



def with_previous_action(t: Trajectory) -> Trajectory:
    """`t` with the action before each step appended to its observation (the first step gets its own action)."""
    obs = np.asarray(t.obs, np.float64).reshape(len(t.obs), -1)
    acts = np.asarray(t.acts, np.float64).reshape(len(t), -1)
    return dataclasses.replace(t, obs=np.c_[obs, np.r_[acts[:1], acts]].astype(np.float32))


def main(argv: list[str] | None = None) -> None:
    from digail.algos.model_selection import heldout_split, smallest_within_one_se
    from digail.algos.segment_init import _FeatureMap, hard_em_from, hard_em_segmentation, heldout_codes_curve
    from digail.algos.segment_models import _design, _LinearPolicies
    from digail.data.minari_io import load_dataset
    from digail.eval.segmentation import segmentation_metrics
    from digail.nets.policy import ActionSpec
    from digail.utils import set_torch_threads

    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("task", choices=task_names())
    parser.add_argument("--ridges", nargs="+", type=float, default=[1.0])
    parser.add_argument("--oracle", action="store_true", help="also the oracle labels' description length")
    parser.add_argument("--curve", choices=["linear", "rff"], help="the K curve with this sub-task model")
    parser.add_argument("--residuals", action="store_true", help="each model's residual on the oracle labels")
    parser.add_argument("--previous-action", action="store_true",
                        help="append the previous action (the first step: its own) to every observation")
    parser.add_argument("--seeds", nargs="+", type=int, default=[0])
    parser.add_argument("--starts", type=int, default=4, help="the start's starts (`hard_em_segmentation`)")
    parser.add_argument("--actions", choices=["auto", "gaussian"], default="auto",
                        help="how the start models continuous actions (`segment_models.ACTION_MODELS`)")
    parser.add_argument("--data", type=Path, default=Path("runs/segbench/datasets"))
    args = parser.parse_args(argv)
    set_torch_threads(1)
    demos, k, _, _ = task_data(args.task, args.data)
    ds = load_dataset(demos)
    discrete = ActionSpec.from_space(ds.action_space).discrete
    trajs = [with_previous_action(t) for t in ds.trajs] if args.previous_action else ds.trajs
    labels = [np.asarray(t.subtasks)[:len(t)] for t in trajs]

    def score(seg: list[np.ndarray]) -> str:
        m = segmentation_metrics(seg, labels)
        return (f"accuracy {m['accuracy']:.3f}, switches {m['switches_per_episode']:.2f} "
                f"(truth {m['true_switches_per_episode']:.2f}), NMI {m['nmi']:.2f}")

    if args.residuals:
        x, a, n_act, _, _ = _design(trajs, discrete)
        codes = np.concatenate(labels)
        for model in ("linear", "rff"):
            p = _FeatureMap(model).fit(x)(x)
            for ridge in args.ridges:
                policies = _LinearPolicies(k, p.shape[1], n_act, discrete, ridge)
                policies.fit(p, a, codes)
                resid = a - np.einsum("td,tda->ta", p, policies.w[codes])
                print(f"{args.task} {model} ridge {ridge}: residual rms {np.sqrt((resid ** 2).sum(1).mean()):.3f}")
        return
    for ridge in args.ridges:
        if args.curve:
            for seed in args.seeds:
                t0 = time.perf_counter()
                train, held = heldout_split(len(trajs), 0.2, seed)
                curve = heldout_codes_curve([trajs[i] for i in train], [trajs[i] for i in held], list(range(2, 9)),
                                            discrete, seed=seed, ridge=ridge, model=args.curve,
                                            actions=args.actions)
                chosen = curve[smallest_within_one_se(curve)]["codes"]
                print(f"{args.task} {args.curve} ridge {ridge} seed {seed}: K = {chosen} (true {k}); DL per step "
                      + " ".join(f"{c['dl_per_step']:.3f}" for c in curve) + "; switches per episode "
                      + " ".join(f"{c['switches_per_episode']:.1f}" for c in curve)
                      + f" ({time.perf_counter() - t0:.0f} s)", flush=True)
            continue
        if args.oracle:  # the labels' costs do not depend on the start's seed
            oracle, _ = hard_em_from(trajs, labels, k, discrete, rounds=0, ridge=ridge, actions=args.actions)
            from_oracle, seg = hard_em_from(trajs, labels, k, discrete, ridge=ridge, actions=args.actions)
            labels_note = f"oracle labels {oracle:.1f}, hard EM from them {from_oracle:.1f} ({score(seg)})"
        for seed in args.seeds:
            t0 = time.perf_counter()
            found = hard_em_segmentation(trajs, k, discrete, seed=seed, ridge=ridge, starts=args.starts,
                                         actions=args.actions)
            line = f"{args.task} ridge {ridge} seed {seed}: {score(found)} ({time.perf_counter() - t0:.0f} s)"
            if args.oracle:
                own, _ = hard_em_from(trajs, found, k, discrete, rounds=0, ridge=ridge, actions=args.actions)
                line += f"; nats: {labels_note}, found {own:.1f}"
            print(line, flush=True)


if __name__ == "__main__":
    main()
