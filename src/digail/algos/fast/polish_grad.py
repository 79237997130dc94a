"""The polish step's loss and gradient written out in one TorchScript function (`step_grads`), for
`digail.algos.polish.fit_to_codes`: a step is a few dozen small operations, so Python and autograd's work per step
is the cost. It runs autograd's own backward kernels on the same numbers, so it gives the reference's bits
(tests/test_vae.py, tests/test_fast_path.py)."""

from __future__ import annotations

import torch
from torch import Tensor

from digail.algos.fast import mlp
from digail.algos.fast.ops import log_softmax_backward


def step_grads(pi_x: Tensor, acts: Tensor, q_x: Tensor, q_codes: Tensor, pi_w: list[Tensor], pi_b: list[Tensor],
                log_std: Tensor, q_w: list[Tensor], q_b: list[Tensor], discrete: bool) -> tuple[list[Tensor], Tensor]:
    """The gradients of the polish loss -mean log pi(a | s, c) + CE(q(s~, c_prev), c) for one minibatch, as
    `loss.backward()` computes them (the same kernels on the same numbers, so the same bits): pi's weights and
    biases, its log-std (continuous), then q's weights and biases; and the loss."""
    mb = pi_x.shape[0]
    losses: list[Tensor] = []
    grads: list[Tensor] = []
    for net in range(2):
        ws, bs = (pi_w, pi_b) if net == 0 else (q_w, q_b)
        out, xs = mlp.forward(pi_x if net == 0 else q_x, ws, bs)
        if net == 0 and not discrete:
            ls = log_std.clamp(-5.0, 2.0)
            e = torch.exp(-ls)
            diff = acts - out
            z = diff * e
            logp = -0.5 * z.pow(2).sum(-1) - ls.sum() - 0.5 * out.shape[-1] * 1.8378770664093453  # log(2 pi)
            losses.append(-logp.mean())
            g_z = (2.0 * z) * (-0.5 * (-1.0 / mb))
            g_ls = -((g_z * diff).sum(0) * e) + torch.full((mb,), 1.0 / mb).sum()  # exp(-ls), then -ls.sum()
            g_ls = torch.where((log_std >= -5.0) & (log_std <= 2.0), g_ls, torch.zeros_like(g_ls))
            g = -(g_z * e)
        else:
            # pi's categorical log-likelihood and q's cross-entropy: log-softmax, then the picked entries' mean
            target = acts if net == 0 else q_codes
            lsm = out.log_softmax(-1)
            losses.append(-lsm.gather(-1, target.long().unsqueeze(-1)).mean())
            g_pick = torch.zeros_like(lsm).scatter_(-1, target.long().unsqueeze(-1), -1.0 / mb)
            g = log_softmax_backward(g_pick, lsm)
            g_ls = g.new_zeros(0)
        g_ws, g_bs, _ = mlp.backward(g, xs, ws, False)
        grads += g_ws + g_bs
        if net == 0 and not discrete:
            grads.append(g_ls)
    return grads, losses[0] + losses[1]
