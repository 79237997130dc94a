"""The sequential Gumbel-softmax chain of the VAE: relaxed one-hot codes c~_t ~ q(. | s_t, c~_{t-1}), one step at a
time, each sample fed as the next step's previous code (paper section 3.1).

`_reference_chain` is the chain as written in the paper, q's module called step by step and differentiated by
autograd; the fast path (`digail.algos.fast.gumbel_chain`: a scripted sampling loop, a hand-written backward pass)
gives the same numbers to float rounding and runs unless `digail.algos.fast` is switched to the reference.
"""

from __future__ import annotations

import torch
import torch.nn.functional as F

from digail.algos import fast
from digail.nets.vae import MacroPolicy


def gumbel_softmax_chain(q: MacroPolicy, obs_n: torch.Tensor, tau: float, hard: bool = False,
                         generator: torch.Generator | None = None,
                         gumbel: torch.Tensor | None = None, bptt: bool = False) -> tuple[torch.Tensor, torch.Tensor]:
    """Draw relaxed codes c~_0 .. c~_{T-1} sequentially from q(. | s_t, c~_{t-1}).

    Args:
        q: the macro-policy (`MacroPolicy`: a ReLU MLP on [obs_n, prev]).
        obs_n: (B, T, obs_dim) normalised observations.
        tau: Gumbel-softmax temperature.
        hard: straight-through: the forward pass uses exact one-hots (also as the next step's previous code),
            the backward pass the relaxed sample's gradient.
        generator: source of the Gumbel noise.
        gumbel: (B, T, K) Gumbel(0, 1) noise to use instead of drawing it (tests, reproductions).
        bptt: backpropagate through q's previous-code input too: the exact gradient of the sequential samples.
            False (the default) stops the gradient at q's previous-code input: the same samples and the same
            gradient except the path from c~_{t-1} into q(. | s_t, c~_{t-1}).

    Returns:
        `(logits, codes)`, both (B, T, K): q's logits at each step (given the sampled previous code) and the
        relaxed (or straight-through hard) samples. Gradients reach q through both.
    """
    B, T, _ = obs_n.shape
    K = q.codes
    if gumbel is None:
        u = torch.rand((T, B, K), generator=generator, device=obs_n.device).clamp_(1e-10, 1.0 - 1e-7)
        gumbel_tm = -torch.log(-torch.log(u))
    else:
        gumbel_tm = gumbel.transpose(0, 1)
    if fast.enabled():
        from digail.algos.fast.gumbel_chain import fast_chain

        return fast_chain(q, obs_n, gumbel_tm, tau, hard, bptt)
    return _reference_chain(q, obs_n, gumbel_tm, tau, hard, bptt)


def _reference_chain(q: MacroPolicy, obs_n: torch.Tensor, gumbel_tm: torch.Tensor, tau: float, hard: bool,
                     bptt: bool) -> tuple[torch.Tensor, torch.Tensor]:
    """The chain step by step through q's module, differentiated by autograd (time-major noise (T, B, K))."""
    B, T, _ = obs_n.shape
    K = q.codes
    prev = obs_n.new_zeros(B, K)
    logits_steps, codes = [], []
    for t in range(T):
        logits = q(obs_n[:, t], prev if bptt else prev.detach())
        y = ((logits + gumbel_tm[t]) / tau).softmax(-1)
        if hard:
            y = F.one_hot(y.argmax(-1), K).to(y.dtype) + (y - y.detach())
        logits_steps.append(logits)
        codes.append(y)
        prev = y
    return torch.stack(logits_steps, 1), torch.stack(codes, 1)
