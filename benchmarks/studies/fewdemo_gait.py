"""What the codes of a VAE trained on few demonstrations mean: their agreement with the hip's gait phase.

    python benchmarks/studies/fewdemo_gait.py VAE_RUN [--env Hopper-v5] [--episodes 4] [--subsample 20] [--seed 0]

q decodes causally (`segment_many`, as the macro-policy runs online) the training demonstrations at the env's own
rate, held-out demonstrations 10-19 of the same dataset, and the training demonstrations as subsampled (what the
VAE was fitted on); each is scored against the gait phase of `digail.eval.gait` (the hip's phase portrait in four
sectors, statistics from the whole dataset): mutual information in bits, NMI, switches per 100 steps. Prints JSON.
"""

from __future__ import annotations

import argparse
import json

import numpy as np


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("vae")
    parser.add_argument("--env", default="Hopper-v5")
    parser.add_argument("--demos", default=None, help="dataset (default: the env's shipped one)")
    parser.add_argument("--episodes", type=int, default=4)
    parser.add_argument("--subsample", type=int, default=20)
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args()
    from digail.algos.decode import segment_many
    from digail.checkpoint import load_model
    from digail.data.demos import default_dataset_id
    from digail.data.minari_io import load_dataset
    from digail.data.subset import select_demos
    from digail.eval.gait import code_phase_scores, gait_phase, phase_stats
    from digail.utils import set_torch_threads

    set_torch_threads(1)
    model, _ = load_model(args.vae)
    trajs = load_dataset(args.demos or default_dataset_id(args.env)).trajs
    stats = phase_stats([np.asarray(t.obs) for t in trajs], args.env)
    sets = {"training demonstrations, every step": trajs[:args.episodes],
            "held-out demonstrations 10-19, every step": trajs[10:20],
            "training demonstrations as subsampled": select_demos(trajs, args.episodes, args.subsample, args.seed)}
    out = {}
    for name, sel in sets.items():
        codes = segment_many(model, sel)
        phases = [gait_phase(np.asarray(t.obs[:-1]), args.env, stats) for t in sel]
        scores = code_phase_scores(codes, phases)
        out[name] = {**{k: round(float(v), 3) for k, v in scores.items()},
                     "codes_used": np.unique(np.concatenate(codes)).tolist()}
    print(json.dumps(out, indent=1))


if __name__ == "__main__":
    main()
