"""The VAE loss of `vae_pretrain.vae_loss` and its gradient written out by hand, in TorchScript.

Why: a Circle-World batch is 16 demonstrations of 120 steps through 2x64 nets, so the work per batch is a few
hundred tiny tensor operations; the autograd engine, the Python between them and the batched recomputation of q's
logits after the sampling chain cost more than the arithmetic. Here one scripted function samples the chain
(keeping q's hidden layers, so q runs once), evaluates the loss on the whole (time, batch) block and backpropagates
by hand: the same maths as `vae_loss` (soft samples, the gradient stopped at q's previous-code input, which is
`bptt` off), with the codes taken from the chain itself rather than from the recomputation, so the numbers agree
to float rounding, not bit for bit (tests/test_vae.py checks the gradients against autograd). Straight-through
(`hard`) and `bptt` keep the autograd path.
"""

from __future__ import annotations

import torch
import torch.nn.functional as F
from torch import Tensor

from digail.algos.fast import mlp
from digail.algos.fast.scripting import scripted
from digail.nets.vae import HierarchicalPolicy


def _loss_and_grads(obs: Tensor, acts: Tensor, mask: Tensor, gumbel: Tensor, tau: float, q_w: list[Tensor],
                    q_b: list[Tensor], pi_w: list[Tensor], pi_b: list[Tensor], log_std: Tensor, table: Tensor,
                    discrete: bool, dec_lo: int, dec_hi: int, kl_coef: float, smooth_coef: float, ent_coef: float,
                    one: float) -> tuple[list[Tensor], Tensor]:
    """Gradients of the VAE loss and its parts for one time-major batch: obs (T, B, D), acts (T, B, A) or (T, B),
    mask (T, B), gumbel (T, B, K).

    Returns `(grads, parts)`: q's weights and biases, pi's weights and biases, log-std (continuous only) and the
    prior table, in that order; `parts` = [total, recon, kl, smooth] (per-step averages). `one` is 1.0 passed as
    an argument so that TorchScript keeps addmm whole (as `gumbel_chain._chain_loop`).
    """
    T, B, D = obs.shape[0], obs.shape[1], obs.shape[2]
    log_2pi = 1.8378770664093453  # log(2 pi): TorchScript reads no module-level floats
    K = q_w[-1].shape[0]
    n = mask.sum()
    m = (mask / n).unsqueeze(-1)  # (T, B, 1): each step's weight in the per-step averages

    # --- the sampling chain: q's hidden layers kept for the backward pass
    rows = T * B  # the batched parts run on 2-D (time x batch, features) views
    pre = F.linear(obs.reshape(rows, D), q_w[0][:, :D], q_b[0]).view(T, B, -1).unbind(0)
    w_prev_t = q_w[0][:, D:].t()
    w_mid_t = [q_w[i].t() for i in range(1, len(q_w) - 1)]
    w_out_t = (q_w[-1] / tau).t()
    noise = ((q_b[-1] + gumbel) / tau).unbind(0)
    n_hidden = len(q_w) - 1
    hidden: list[list[Tensor]] = [[] for _ in range(n_hidden)]
    samples: list[Tensor] = []
    prev = obs.new_zeros(B, K)
    for t in range(T):  # views from `unbind`: indexing a list costs less than a tensor `select` per step
        h = torch.addmm(pre[t], prev, w_prev_t, beta=one, alpha=one).relu_()
        hidden[0].append(h)
        for i in range(n_hidden - 1):
            h = torch.addmm(q_b[i + 1], h, w_mid_t[i], beta=one, alpha=one).relu_()
            hidden[i + 1].append(h)
        prev = torch.addmm(noise[t], h, w_out_t, beta=one, alpha=one).softmax(-1)
        samples.append(prev)
    hs = [torch.stack(layer).view(rows, -1) for layer in hidden]
    codes = torch.stack(samples)  # (T, B, K) relaxed samples c~_t
    prev_codes = torch.cat([obs.new_zeros(1, B, K), codes[:-1]])
    logits = F.linear(hs[-1], q_w[-1], q_b[-1]).view(T, B, K)

    # --- decoder pi(a_t | s_t, c~_t)
    out_2d, acts_in = mlp.forward(torch.cat([obs[:, :, dec_lo:dec_hi], codes], -1).view(rows, -1), pi_w, pi_b)
    out = out_2d.view(T, B, -1)
    grads_tail: list[Tensor] = []
    if discrete:
        logp_all = out.log_softmax(-1)
        idx = acts.long().unsqueeze(-1)
        logp = logp_all.gather(-1, idx).squeeze(-1)
        g_out = (logp_all.exp() - torch.zeros_like(out).scatter_(-1, idx, 1.0)) * m
    else:
        ls = log_std.clamp(-5.0, 2.0)
        inv_std = torch.exp(-ls)
        z = (acts - out) * inv_std
        logp = -0.5 * z.pow(2).sum(-1) - ls.sum() - 0.5 * out.shape[-1] * log_2pi
        g_out = -(z * inv_std) * m
        inside = ((log_std >= -5.0) & (log_std <= 2.0)).to(log_std.dtype)
        grads_tail.append(-((z * z - 1.0) * m).sum((0, 1)) * inside)
    recon = -(logp * mask).sum() / n

    # --- KL(q(. | s_t, c~_{t-1}) || p(. | c~_{t-1})), the entropy bonus, the smoothing penalty
    prior_logits = prev_codes @ table[:-1]
    prior_logits[0] += table[-1]  # c~_{-1} is the zero start vector: its row is the table's last
    log_q = logits.log_softmax(-1)
    q = log_q.exp()
    log_p = prior_logits.log_softmax(-1)
    kl_bt = (q * (log_q - log_p)).sum(-1, keepdim=True)
    kl = (kl_bt.squeeze(-1) * mask).sum() / n
    ent_bt = -(q * log_q).sum(-1, keepdim=True)
    g_logits = m * (kl_coef * q * (log_q - log_p - kl_bt) + ent_coef * q * (log_q + ent_bt))
    g_prior = (kl_coef * m) * (log_p.exp() - q)
    g_table = torch.cat([prev_codes.reshape(-1, K).t() @ g_prior.reshape(-1, K), g_prior[0].sum(0, keepdim=True)])

    a, b = codes[:-1], codes[1:]
    na, nb = torch.linalg.vector_norm(a, 2.0, [-1], True), torch.linalg.vector_norm(b, 2.0, [-1], True)
    big = torch.maximum(na, nb)
    den = big.clamp_min(1e-8)
    dot = (a * b).sum(-1, keepdim=True)
    smooth = ((1.0 - dot / den).squeeze(-1) * mask[1:]).sum() / n
    # d den / d |a|: torch.maximum's gradient (split evenly on a tie), zero below the clamp
    live = (big >= 1e-8).to(a.dtype)
    wa = torch.where(na > nb, torch.ones_like(na), torch.where(na == nb, 0.5 * torch.ones_like(na),
                                                                torch.zeros_like(na))) * live
    wb = live - wa
    g_s = smooth_coef * m[1:]
    coef = dot / (den * den)
    g_codes = g_prior @ table[:-1].t()  # the prior's input: c~_{t-1} feeds step t
    g_codes = torch.cat([g_codes[1:], g_codes.new_zeros(1, B, K)])
    g_codes[:-1] += g_s * (coef * wa * a / na - b / den)
    g_codes[1:] += g_s * (coef * wb * b / nb - a / den)

    # --- back through the decoder: its weights, and its code input
    g_pi_w, g_pi_b, g_h = mlp.backward(g_out.view(rows, -1), acts_in, pi_w, True)
    g_codes = g_codes + (g_h @ pi_w[0][:, pi_w[0].shape[1] - K:]).view(T, B, K)

    # --- codes = softmax((logits + gumbel) / tau), then q's layers (its previous-code input held fixed)
    g_logits = g_logits + codes * (g_codes - (g_codes * codes).sum(-1, keepdim=True)) / tau
    g_q_w, g_q_b, _ = mlp.backward(g_logits.view(rows, K), [torch.cat([obs, prev_codes], -1).view(rows, -1)] + hs,
                                   q_w, True)

    total = recon + kl_coef * kl + smooth_coef * smooth - ent_coef * (ent_bt.squeeze(-1) * mask).sum() / n
    grads = g_q_w + g_q_b + g_pi_w + g_pi_b + grads_tail + [g_table]
    return grads, torch.stack([total, recon, kl, smooth])


class VAEGrad:
    """Sets the VAE loss's gradient on the model's parameters (`.grad`) for one batch; returns the loss parts.

    Built once per training: it holds the parameter lists in the order `_loss_and_grads` returns their gradients.
    """

    def __init__(self, model: HierarchicalPolicy) -> None:
        self.model = model
        q_lin = [m for m in model.q.net if isinstance(m, torch.nn.Linear)]
        pi_lin = [m for m in model.pi.net if isinstance(m, torch.nn.Linear)]
        self.q_w, self.q_b = [m.weight for m in q_lin], [m.bias for m in q_lin]
        self.pi_w, self.pi_b = [m.weight for m in pi_lin], [m.bias for m in pi_lin]
        self.discrete = model.action.discrete
        self.log_std = model.pi.log_std if not self.discrete else model.prior.table  # unused when discrete
        self.targets = [*self.q_w, *self.q_b, *self.pi_w, *self.pi_b, *([] if self.discrete else [self.log_std]),
                        model.prior.table]
        lo_hi = model.pi.decoder_obs or (0, model.obs_dim)
        self.dec_lo, self.dec_hi = int(lo_hi[0]), int(lo_hi[1])

    def __call__(self, obs_n: Tensor, acts: Tensor, mask: Tensor, gumbel: Tensor, tau: float, kl_coef: float,
                 smooth_coef: float, ent_coef: float) -> dict[str, float]:
        """Time-major inputs (T, B, ...); the coefficients already include the warm-up factor."""
        with torch.no_grad():
            grads, parts = scripted(_loss_and_grads)(
                obs_n, acts, mask, gumbel, tau, self.q_w, self.q_b, self.pi_w, self.pi_b, self.log_std,
                self.model.prior.table, self.discrete, self.dec_lo, self.dec_hi, kl_coef, smooth_coef, ent_coef, 1.0)
        for p, g in zip(self.targets, grads, strict=True):
            p.grad = g if p.requires_grad else None
        total, recon, kl, smooth = parts.tolist()
        return {"losses/total": total, "losses/recon": recon, "losses/kl": kl, "losses/smooth": smooth}
