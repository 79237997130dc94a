"""The fast path, and the one switch between it and the reference path.

The reference path is every network and loss written once through the modules, differentiated by autograd, with
torch's own optimiser step; the fast path is what pays at the small nets digail trains, each piece measured
(`benchmarks/studies/fast_path.py`) and tied to the reference by an equivalence test (the contract,
tests/test_fast_path.py):

- `inference`: NumPy forward passes of pi, V and q for the rollouts (reference: `digail.algos.inference`'s
  `ModuleActorCritic` and `ModuleCodeNet`; tests/test_fast.py);
- `step.LeanStep`: gradient clipping and fused Adam as direct foreach calls (tests/test_ppo.py, bit for bit);
- `ppo_grad`, `vae_grad`, `polish_grad`, `scripting`: the PPO minibatch's, the VAE's and the polish step's loss with
  a hand-written gradient in one TorchScript function (tests/test_ppo_grad.py, tests/test_vae.py: to float
  rounding; the polish's bit for bit);
- `gumbel_chain`: the VAE's sequential Gumbel-softmax chain with a scripted sampling loop and a hand-written
  backward pass (reference: `digail.algos.gumbel._reference_chain`; tests/test_vae.py);
- `sac_grad` with `step.FusedAdamState`: a whole SAC update (both gradients, the fused Adam steps on the
  optimisers' own state, the Polyak step) and D's step as one TorchScript call each (tests/test_sac.py: to float
  rounding against autograd, bit for bit against the same gradients with torch's own optimiser steps).

`DIGAIL_REFERENCE=1` in the environment (or `reference()` in code) turns every piece off: the updates then run
through autograd and `torch.optim`, the rollouts through the modules' forward passes, slower, with the same
numbers to float rounding.
"""

from __future__ import annotations

import contextlib
import os
from collections.abc import Iterator

_forced_reference = False


def enabled() -> bool:
    """Whether the fast path runs (not `DIGAIL_REFERENCE=1`, not inside `reference()`)."""
    return not _forced_reference and os.environ.get("DIGAIL_REFERENCE", "0") in ("", "0")


@contextlib.contextmanager
def reference() -> Iterator[None]:
    """Run the block on the reference path (for the equivalence tests)."""
    global _forced_reference
    before, _forced_reference = _forced_reference, True
    try:
        yield
    finally:
        _forced_reference = before
