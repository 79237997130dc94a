"""The polish step's loss and gradient written out in one TorchScript function (`step_grads`), for
`digail.algos.polish.fit_to_codes`: a step is a few dozen small operations, so Python and autograd's work per step
is the cost. It runs autograd's own backward kernels on the same numbers, so it gives the reference's bits
(tests/test_vae.py, tests/test_fast_path.py)."""

from __future__ import annotations

import torch
import torch.nn.functional as F
from torch import Tensor

from digail.algos.fast.ops import log_softmax_backward, relu_backward


def _linear_backward(g: Tensor, x: Tensor, w: Tensor) -> tuple[Tensor, Tensor, Tensor]:
    """Autograd's backward of `F.linear(x, w, b)` for 2-D x: the weight's (g^T x, its orientation for a
    transposed weight), the bias's and the input's gradients."""
    return g.t().mm(x), g.sum(0), g.mm(w)


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
        xs = [pi_x if net == 0 else q_x]
        for i in range(len(ws) - 1):
            xs.append(torch.relu(F.linear(xs[-1], ws[i], bs[i])))
        out = F.linear(xs[-1], ws[-1], bs[-1])
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
        g_ws: list[Tensor] = []
        g_bs: list[Tensor] = []
        for i in range(len(ws) - 1, -1, -1):
            g_w, g_b, g_in = _linear_backward(g, xs[i], ws[i])
            g_ws.append(g_w)
            g_bs.append(g_b)
            if i > 0:
                g = relu_backward(g_in, xs[i])
        g_ws.reverse()
        g_bs.reverse()
        grads += g_ws + g_bs
        if net == 0 and not discrete:
            grads.append(g_ls)
    return grads, losses[0] + losses[1]
