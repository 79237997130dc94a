"""The fast path, and the one switch between it and the reference path.

The reference path is every network and loss written once through the modules, differentiated by autograd, with
torch's own optimiser step; the fast path is what pays at the small nets digail trains. Each piece stays only
where it makes a whole training iteration (or pre-training epoch) at least 1.3x faster than the reference path
with `torch.compile` where that applies (`benchmarks/studies/fast_path.py`), and is tied to the reference by an
equivalence test (tests/test_fast_path.py):

- `inference`: NumPy forward passes of pi, V and q for PPO's rollouts (reference: `digail.algos.inference`'s
  `ModuleActorCritic` and `ModuleCodeNet`; tests/test_fast.py);
- `ppo_grad`: PPO's minibatch loss and gradient in one TorchScript function, for minibatches of up to
  `digail.algos.ppo.HAND_GRAD_MAX_ROWS` rows (tests/test_ppo_grad.py: to float rounding);
- `sac_grad` with `step.FusedAdamState`: a whole SAC update (both gradients, the Adam steps on the optimisers'
  own state, the Polyak step) and D's step with its gradient penalty as one TorchScript call each
  (tests/test_sac.py: to float rounding against autograd, bit for bit against the same gradients with torch's
  own optimiser steps);
- `vae_grad`, `gumbel_chain`, `polish_grad`: the VAE's loss and gradient, its sequential Gumbel-softmax chain
  (reference: `digail.algos.gumbel._reference_chain`) and the polish step's loss and gradient (tests/test_vae.py;
  the polish's bit for bit).

They share one ReLU MLP forward and backward pass (`mlp`) and call torch's private ops only through `ops`, whose
`adam_step` is the one Adam written out (inside the scripted SAC and D steps); every other optimiser step is
torch's own. `DIGAIL_REFERENCE=1` in the environment (or `reference()`
in code) turns every piece off: the updates then run through autograd, the rollouts through the modules' forward
passes, slower, with the same numbers to float rounding. So does a torch the fast path is not tested on (`ops`,
with one warning). A trainer reads the switch once, when it is built, records it (`GAIL.fast_path`, the run's
config.json) and runs every iteration under that value (`pinned`).
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
