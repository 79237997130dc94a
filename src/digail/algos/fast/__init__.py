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
numbers to float rounding. So does a torch the fast path is not tested on (`ops`, with one warning). A trainer
reads the switch once, when it is built, records it (`GAIL.fast_path`, the run's config.json) and runs every
iteration under that value (`pinned`).
"""

from __future__ import annotations

import contextlib
import os
from collections.abc import Iterator

from digail.algos.fast import ops

_pinned: bool | None = None


def enabled() -> bool:
    """Whether the fast path runs: inside `pinned(on)` (and `reference()`), `on`; elsewhere unless
    `DIGAIL_REFERENCE=1`. Never on a torch the fast path is not tested on (`ops.problem`)."""
    if ops.problem is not None:
        return False
    if _pinned is not None:
        return _pinned
    return os.environ.get("DIGAIL_REFERENCE", "0") in ("", "0")


@contextlib.contextmanager
def pinned(on: bool) -> Iterator[None]:
    """Run the block with the fast path on or off, whatever the environment says."""
    global _pinned
    before, _pinned = _pinned, on
    try:
        yield
    finally:
        _pinned = before


def reference() -> contextlib.AbstractContextManager[None]:
    """Run the block on the reference path (for the equivalence tests)."""
    return pinned(False)
