"""TorchScript for the hand-written loops of VAE training (the Gumbel-softmax chain, the VAE's loss and gradient,
the polish step): each runs many tiny ops where the interpreter between them costs more than their arithmetic."""

from __future__ import annotations

import functools
from collections.abc import Callable
from typing import Any

import torch


@functools.cache
def scripted(fn: Callable[..., Any]) -> Callable[..., Any]:
    """`fn` compiled by TorchScript, once per process; `fn` itself where this torch cannot script it (the same
    numbers, slower)."""
    try:
        return torch.jit.script(fn)
    except Exception:  # TorchScript unavailable or changed
        return fn
