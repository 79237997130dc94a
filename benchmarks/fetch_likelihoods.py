"""Fetch: how the hard-EM start's action likelihood decides K = 4 against K = 2 (issue 14; docs/experiments.md,
"The gripper command's likelihood").

    python benchmarks/fetch_likelihoods.py > benchmarks/results/fetch_likelihoods.txt

On the shipped FetchPickAndPlace demonstrations, the start alone (`hard_em_segmentation`, seeds 0 1 2, learned
switch costs) under four likelihoods of the action `[dx, dy, dz, grip]`, scored against the four phases (K = 4) and
against pick / place (K = 2, phases 0 1 -> 0, 2 3 -> 1):

- `gaussian`: every dimension Gaussian around a linear policy per code, one variance per dimension (the default
  before session 7);
- `gaussian+capped`: the same with each dimension's cost capped, a mixture with 0.1% uniform over the range the
  demonstrations span (`segment_init.OUTLIER_SHARE`, the default since session 7);
- `logistic`: the two-valued finger command Bernoulli, its log-odds linear in the state per code (a code can then
  say "close once the gripper is at the object"), the motion as before;
- `logistic+capped`: also the motion's per-dimension cost capped, here with 1% uniform, so a few steps no linear
  policy fits (the first carry step's jump) do not earn a code;
- `constant+capped`: the finger command Bernoulli with one rate per code (Laplace-smoothed), the motion capped.

Per variant, task and seed: accuracy and switches per episode (truth 3 and 1); per variant and task, seed 0's
description length, the oracle labels' and that of hard EM started from them.
"""

from __future__ import annotations

import math
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from segmentation import task_data  # noqa: E402

from digail.algos import segment_init  # noqa: E402
from digail.algos.segment_init import _LinearPolicies, _softmax_regression  # noqa: E402
from digail.data.minari_io import load_dataset  # noqa: E402
from digail.eval.segmentation import segmentation_metrics  # noqa: E402

OUTLIER_SHARE = 0.01


def policies_class(fingers: str, capped: bool) -> type[_LinearPolicies]:
    """A `_LinearPolicies` whose two-valued action dimensions are Bernoulli (`fingers`: "logistic" or "constant")
    and whose Gaussian dimensions are optionally capped (module docstring)."""

    class Policies(_LinearPolicies):
        binary: list[int] | None = None

        def fit(self, x: np.ndarray, a: np.ndarray, codes: np.ndarray) -> None:
            if self.binary is None:
                self.binary = [d for d in range(a.shape[1]) if len(np.unique(a[:, d])) == 2]
                self.high = {d: np.unique(a[:, d])[1] for d in self.binary}
                self.span = a.max(0) - a.min(0)
                self.wb = np.zeros((self.k, x.shape[1], len(self.binary), 2))
            super().fit(x, a, codes)  # the Gaussian dimensions (and the unused Gaussian fit of the binary ones)
            for j in range(self.k):
                sel = codes == j
                for i, d in enumerate(self.binary):
                    y = (a[sel, d] == self.high[d]).astype(np.int64)
                    if not sel.any():
                        continue
                    if fingers == "constant":
                        p = (y.sum() + 1) / (len(y) + 2)
                        self.wb[j, :, i] = 0.0
                        self.wb[j, -1, i] = [math.log(1 - p), math.log(p)]
                    else:
                        self.wb[j, :, i] = _softmax_regression(x[sel], y, 2, self.wb[j, :, i], self.ridge * 1e-3)

        def loglik(self, x: np.ndarray, a: np.ndarray) -> np.ndarray:
            assert self.binary is not None
            cont = [d for d in range(a.shape[1]) if d not in self.binary]
            mean = np.einsum("td,kda->tka", x, self.w)[..., cont]
            var = np.exp(self.log_var[:, cont])[None]
            g = -0.5 * ((a[:, None, cont] - mean) ** 2 / var + np.log(var) + math.log(2 * math.pi))
            if capped:
                g = np.logaddexp(math.log(1 - OUTLIER_SHARE) + g, math.log(OUTLIER_SHARE) - np.log(self.span[cont]))
            out = g.sum(-1)
            for i, d in enumerate(self.binary):
                z = np.einsum("td,kdc->tkc", x, self.wb[:, :, i])
                logp = z - np.logaddexp(z[..., :1], z[..., 1:])
                out = out + logp[..., 1] * (a[:, d] == self.high[d])[:, None] + \
                    logp[..., 0] * (a[:, d] != self.high[d])[:, None]
            return out

    return Policies


# name: (the finger command's model, None for the library's Gaussian; the library's outlier share)
VARIANTS = {"gaussian": (None, 0.0), "gaussian+capped": (None, segment_init.OUTLIER_SHARE),
            "logistic": (("logistic", False), 0.0), "logistic+capped": (("logistic", True), 0.0),
            "constant+capped": (("constant", True), 0.0)}


def main() -> None:
    demos, _, _, _ = task_data("fetch", Path("runs/segbench/datasets"))
    ds = load_dataset(demos)
    phases = [np.asarray(t.subtasks)[:len(t)] for t in ds.trajs]
    tasks = {"K = 4 (phases)": (4, phases), "K = 2 (pick / place)": (2, [np.minimum(p // 2, 1) for p in phases])}
    original = segment_init._LinearPolicies
    for name, (spec, share) in VARIANTS.items():
        segment_init._LinearPolicies = original if spec is None else policies_class(*spec)  # type: ignore[misc]
        try:
            for task, (k, labels) in tasks.items():
                rows = []
                for seed in (0, 1, 2):
                    seg = segment_init.hard_em_segmentation(ds.trajs, k, False, seed=seed, outlier_share=share)
                    m = segmentation_metrics(seg, labels)
                    rows.append(f"{m['accuracy']:.3f} ({m['switches_per_episode']:.2f})")
                    if seed == 0:
                        found = segment_init.hard_em_from(ds.trajs, seg, k, False, rounds=0, outlier_share=share)[0]
                oracle = segment_init.hard_em_from(ds.trajs, labels, k, False, rounds=0, outlier_share=share)[0]
                drift_cost, drift = segment_init.hard_em_from(ds.trajs, labels, k, False, outlier_share=share)
                print(f"{name:16s} {task:21s} accuracy (switches/episode), seeds 0 1 2: {' / '.join(rows)}; "
                      f"nats: found {found:.1f}, oracle {oracle:.1f}, EM from the oracle {drift_cost:.1f} at "
                      f"{segmentation_metrics(drift, labels)['accuracy']:.3f}", flush=True)
        finally:
            segment_init._LinearPolicies = original  # type: ignore[misc]


if __name__ == "__main__":
    main()
