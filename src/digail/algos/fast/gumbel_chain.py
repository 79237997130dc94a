"""The fast Gumbel-softmax chain of `digail.algos.gumbel.gumbel_softmax_chain`: the sampling loop in TorchScript
and `GumbelChain`, the sequential part as one autograd node with hand-written backpropagation.

Only the chain is sequential. The first layer of q is split into its state and code parts; the state part for every
step, the Gumbel noise and the output bias are computed before the time loop, so each step costs one small matrix
product per layer and a softmax. The reference is `gumbel._reference_chain` (q's module called step by step,
differentiated by autograd); tests/test_fast_path.py and tests/test_vae.py hold the two together.
"""

from __future__ import annotations

from typing import Any

import torch
import torch.nn.functional as F
from torch import nn

from digail.algos.fast.ops import relu_backward, softmax_backward
from digail.algos.fast.scripting import scripted
from digail.nets.mlp import mlp_apply
from digail.nets.vae import MacroPolicy


def fast_chain(q: MacroPolicy, obs_n: torch.Tensor, gumbel_tm: torch.Tensor, tau: float, hard: bool,
               bptt: bool) -> tuple[torch.Tensor, torch.Tensor]:
    """`gumbel_softmax_chain` on the fast path, given the time-major Gumbel noise (T, B, K)."""
    linears = [m for m in q.net if isinstance(m, nn.Linear)]
    first, middle, last = linears[0], linears[1:-1], linears[-1]
    D = obs_n.shape[2]
    K = last.out_features
    # Everything that does not depend on the previous code is computed for all steps at once, time-major.
    pre = F.linear(obs_n, first.weight[:, :D], first.bias).transpose(0, 1)
    noise = (last.bias + gumbel_tm) / tau
    mids = [t for m in middle for t in (m.weight, m.bias)]
    if bptt:
        codes, h_last = GumbelChain.apply(hard, pre, first.weight[:, D:], last.weight / tau, noise, *mids)
        logits = F.linear(h_last, last.weight, last.bias)
        return logits.transpose(0, 1), codes.transpose(0, 1)
    with torch.no_grad():
        fed = _sample_chain(hard, pre, first.weight[:, D:], last.weight / tau, noise, *mids)
    prev = torch.cat([torch.zeros_like(fed[:1]), fed[:-1]]).transpose(0, 1)
    # q(obs_n, prev) as bare operations (`mlp_apply`: the same numbers without the module calls)
    logits = mlp_apply([(m.weight, m.bias) for m in linears], torch.cat([obs_n, prev], -1))
    codes = ((logits + gumbel_tm.transpose(0, 1)) / tau).softmax(-1)
    if hard:
        codes = F.one_hot(codes.argmax(-1), K).to(codes.dtype) + (codes - codes.detach())
    return logits, codes


def _sample_chain(hard: bool, pre: torch.Tensor, w_prev: torch.Tensor, w_out: torch.Tensor, noise: torch.Tensor,
                  *mids: torch.Tensor) -> torch.Tensor:
    """The sampling loop of `GumbelChain` alone (no gradient, nothing kept): the codes fed forward (T, B, K).

    The loop runs in TorchScript (`scripting.scripted`) without the Python interpreter between its ~6 T tiny
    operations; the kernels and their order are the Python loop's, so are the bits (tests/test_vae.py).
    """
    w_ts = [mids[i].t() for i in range(0, len(mids), 2)]
    b_s = [mids[i + 1] for i in range(0, len(mids), 2)]
    return scripted(_chain_loop)(hard, pre, w_prev.t(), w_out.t(), noise, w_ts, b_s, 1.0)


def _chain_loop(hard: bool, pre: torch.Tensor, w_prev_t: torch.Tensor, w_out_t: torch.Tensor, noise: torch.Tensor,
                w_ts: list[torch.Tensor], b_s: list[torch.Tensor], one: float) -> torch.Tensor:
    """Per time step: h = relu(pre_t + prev @ w_prev_t), the middle layers, then prev = softmax(h @ w_out_t +
    noise_t). `one` (1.0) is addmm's beta and alpha as an argument: TorchScript splits an addmm whose beta and
    alpha are the constant 1 into a matrix product and an addition, which rounds differently from eager's addmm."""
    K = w_out_t.shape[1]
    prev = pre.new_zeros(pre.shape[1], K)
    fed: list[torch.Tensor] = []
    for t in range(pre.shape[0]):
        h = torch.addmm(pre[t], prev, w_prev_t, beta=one, alpha=one).relu_()
        for i in range(len(w_ts)):
            h = torch.addmm(b_s[i], h, w_ts[i], beta=one, alpha=one).relu_()
        prev = torch.addmm(noise[t], h, w_out_t, beta=one, alpha=one).softmax(-1)
        if hard:
            prev = F.one_hot(prev.argmax(-1), K).to(prev.dtype)
        fed.append(prev)
    return torch.stack(fed)


class GumbelChain(torch.autograd.Function):
    """The sequential part of `fast_chain` as one autograd node with hand-written backpropagation.

    Per step t: h_1 = relu(pre_t + prev_{t-1} @ w_prev.T), h_i = relu(h_{i-1} @ w_i.T + b_i),
    y_t = softmax(h_L @ w_out.T + noise_t), prev_t = y_t (or its one-hot when `hard`, straight-through).

    Why by hand: the loop is the whole cost of pre-training, and on a CPU that cost is the number of tiny tensor
    operations per step. The backward loop below carries only the gradient flowing into the previous code (six
    operations a step); every weight gradient is then one matrix product over all steps. Outputs: the codes fed
    forward (T, B, K) and the last hidden layer (T, B, H_L), from which the caller computes q's logits with
    ordinary autograd. Checked against plain autograd in tests/test_vae.py.
    """

    @staticmethod
    def forward(ctx: Any, hard: bool, pre: torch.Tensor, w_prev: torch.Tensor, w_out: torch.Tensor,
                noise: torch.Tensor, *mids: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        T, B, _ = pre.shape
        K = w_out.shape[0]
        pairs = [(mids[i].t(), mids[i + 1]) for i in range(0, len(mids), 2)]
        w_prev_t, w_out_t = w_prev.t(), w_out.t()
        prev = pre.new_zeros(B, K)
        layers: list[list[torch.Tensor]] = [[] for _ in range(len(pairs) + 1)]
        soft, fed = [], []
        for pre_t, noise_t in zip(pre.unbind(0), noise.unbind(0), strict=True):
            h = torch.addmm(pre_t, prev, w_prev_t).relu_()
            layers[0].append(h)
            for i, (w_t, b) in enumerate(pairs):
                h = torch.addmm(b, h, w_t).relu_()
                layers[i + 1].append(h)
            y = torch.addmm(noise_t, h, w_out_t).softmax(-1)
            soft.append(y)
            prev = F.one_hot(y.argmax(-1), K).to(y.dtype) if hard else y
            fed.append(prev)
        hs = [torch.stack(hl) for hl in layers]
        y_soft = torch.stack(soft)
        y_fed = torch.stack(fed) if hard else y_soft
        ctx.save_for_backward(y_soft, y_fed, w_prev, w_out, *hs, *mids)
        ctx.n_mid = len(pairs)
        return y_fed, hs[-1]

    @staticmethod
    def backward(ctx: Any, g_codes: torch.Tensor, g_hidden: torch.Tensor) -> tuple[torch.Tensor | None, ...]:
        y_soft, y_fed, w_prev, w_out, *rest = ctx.saved_tensors
        n_mid = ctx.n_mid
        hs, mids = rest[:n_mid + 1], rest[n_mid + 1:]
        weights = [mids[2 * i] for i in range(n_mid)]
        y_steps, g_code_steps, g_hidden_steps = y_soft.unbind(0), g_codes.unbind(0), g_hidden.unbind(0)
        h_steps = [h.unbind(0) for h in hs]
        T = len(y_steps)
        g_z_steps: list[torch.Tensor] = []
        g_a_steps: list[list[torch.Tensor]] = [[] for _ in hs]
        g_y = g_code_steps[-1]
        for t in range(T - 1, -1, -1):
            # softmax, then each ReLU layer down to the first; straight-through uses the soft sample's Jacobian
            g_z = softmax_backward(g_y, y_steps[t])
            g_z_steps.append(g_z)
            g_h = torch.addmm(g_hidden_steps[t], g_z, w_out)
            for i in range(n_mid, 0, -1):
                g_a = relu_backward(g_h, h_steps[i][t])
                g_a_steps[i].append(g_a)
                g_h = g_a @ weights[i - 1]
            g_a = relu_backward(g_h, h_steps[0][t])
            g_a_steps[0].append(g_a)
            if t > 0:  # the code fed at step t - 1 gets its own gradient plus what flowed back through q
                g_y = torch.addmm(g_code_steps[t - 1], g_a, w_prev)
        g_z_all = torch.stack(g_z_steps[::-1])
        g_a_all = [torch.stack(steps[::-1]) for steps in g_a_steps]
        prev_all = torch.cat([torch.zeros_like(y_fed[:1]), y_fed[:-1]])

        def outer(a: torch.Tensor, b: torch.Tensor) -> torch.Tensor:
            return a.reshape(-1, a.shape[-1]).t() @ b.reshape(-1, b.shape[-1])

        g_mids: list[torch.Tensor] = []
        for i in range(n_mid):
            g_mids += [outer(g_a_all[i + 1], hs[i]), g_a_all[i + 1].sum((0, 1))]
        return (None, g_a_all[0], outer(g_a_all[0], prev_all), outer(g_z_all, hs[-1]), g_z_all, *g_mids)
