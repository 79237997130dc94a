"""PPO's minibatch loss and its gradient written out by hand, in TorchScript (continuous actions).

Why: a Circle-World minibatch is 128 rows through 2x64 nets (plus 256 rows of the anchor term), so a step is a
few dozen tiny tensor operations whose dispatch, autograd bookkeeping and the Python between them cost far more
than the arithmetic (~2.7 ms per step, half of it in the backward pass). Here one scripted function runs pi and V
forward, evaluates `ppo.minibatch_loss` (clipped surrogate, value loss, Gaussian entropy) and the optional anchor
term, and backpropagates by hand: the same maths as autograd, to float rounding (tests/test_ppo_grad.py checks the
gradients in float64). Discrete actions, the BC term and `PPOConfig.compile` keep the autograd path.
"""

from __future__ import annotations

import torch
from torch import Tensor

from digail.algos.fast import mlp
from digail.algos.fast.scripting import scripted
from digail.nets.critic import ValueNet
from digail.nets.policy import SubtaskPolicy


def _minibatch_grads(x_pi: Tensor, x_v: Tensor, acts: Tensor, logp_old: Tensor, adv: Tensor, returns: Tensor,
                     x_anchor: Tensor, target: Tensor, pi_w: list[Tensor], pi_b: list[Tensor], log_std: Tensor,
                     v_w: list[Tensor], v_b: list[Tensor], clip: float, vf_coef: float, ent_coef: float,
                     anchor_coef: float) -> tuple[list[Tensor], Tensor, Tensor]:
    """Gradients of `minibatch_loss(...) + anchor_coef * anchor` for one minibatch of B rows.

    `x_pi` / `x_v` are pi's and V's inputs (B, .), `adv` the (normalised) advantages; `x_anchor` (N, .) are pi's
    inputs on the anchor term's rows and `target` (N, A) the frozen policy's means there (N = 0: no anchor term).
    Returns `(grads, parts, log_ratio)`: pi's weights and biases, log-std, V's weights and biases, in that order;
    `parts` = [policy, value, entropy, anchor] losses; the detached log pi - log pi_old per row.
    """
    log_2pi = 1.8378770664093453  # log(2 pi): TorchScript reads no module-level floats
    B = x_pi.shape[0]
    n_anchor = x_anchor.shape[0]
    # pi runs once over the minibatch's rows and the anchor's together
    x_all = torch.cat([x_pi, x_anchor]) if n_anchor > 0 else x_pi
    out_all, pi_xs = mlp.forward(x_all, pi_w, pi_b)
    out = out_all[:B]

    # --- the clipped surrogate on the Gaussian's log-likelihood (`SubtaskPolicy.head_log_prob_entropy`); tensors
    # come first in products with Python floats, since TorchScript turns a leading float into a tensor each call
    A = out.shape[-1]
    ls = log_std.clamp(-5.0, 2.0)
    inv_std = ls.neg().exp()
    z = (acts - out) * inv_std
    zz = z * z
    ls_sum = ls.sum()
    logp = zz.sum(-1) * -0.5 - ls_sum - 0.5 * A * log_2pi
    log_ratio = logp - logp_old
    ratio = log_ratio.exp()
    unclipped = ratio * adv
    clipped = ratio.clamp(1.0 - clip, 1.0 + clip) * adv
    pg_loss = torch.minimum(unclipped, clipped).mean().neg()
    entropy = ls_sum + 0.5 * A * (1.0 + log_2pi)
    # d min / d ratio as autograd takes it: the smaller side's, split evenly on a tie; the clamp passes its
    # gradient on [1 - clip, 1 + clip], bounds included
    in_clip = ((ratio >= 1.0 - clip) & (ratio <= 1.0 + clip)).to(ratio.dtype)
    w = torch.where(unclipped < clipped, 1.0, torch.where(unclipped > clipped, in_clip, (in_clip + 1.0) * 0.5))
    g_logp = (adv * w * ratio * (-1.0 / B)).unsqueeze(-1)  # d pg_loss / d logp, as a column
    g_out = g_logp * z * inv_std
    in_range = ((log_std >= -5.0) & (log_std <= 2.0)).to(log_std.dtype)
    g_log_std = ((g_logp * (zz - 1.0)).sum(0) - ent_coef) * in_range

    # --- the anchor: squared distance of pi's means to the frozen policy's on the anchor rows
    anchor = out.new_zeros(())
    if n_anchor > 0:
        diff = out_all[B:] - target
        anchor = (diff * diff).sum(-1).mean()
        g_out = torch.cat([g_out, diff * (2.0 * anchor_coef / n_anchor)])
    g_pi_w, g_pi_b, _ = mlp.backward(g_out, pi_xs, pi_w, False)

    # --- the value loss 0.5 (V - R)^2, averaged
    v_out, v_xs = mlp.forward(x_v, v_w, v_b)
    err = v_out.squeeze(-1) - returns
    v_loss = (err * err).mean() * 0.5
    g_v_w, g_v_b, _ = mlp.backward((err * (vf_coef / B)).unsqueeze(-1), v_xs, v_w, False)

    grads = g_pi_w + g_pi_b + [g_log_std] + g_v_w + g_v_b
    return grads, torch.stack([pg_loss, v_loss, entropy, anchor]), log_ratio


class PPOGrad:
    """Sets one minibatch's PPO gradient on pi's and V's parameters (`.grad`); returns its loss parts and
    log-ratios. Built once per update: it holds the parameter lists in the order `_minibatch_grads` returns
    their gradients, and `applies` says whether it covers these nets (a Gaussian policy, both nets plain `mlp`s).
    """

    def __init__(self, policy: SubtaskPolicy, value: ValueNet) -> None:
        pi_lin, v_lin = mlp.plain_layers(policy.net), mlp.plain_layers(value.net)
        self.applies = pi_lin is not None and v_lin is not None and not policy.action.discrete
        pi_lin, v_lin = pi_lin or [], v_lin or []
        self.pi_w, self.pi_b = [m.weight for m in pi_lin], [m.bias for m in pi_lin]
        self.v_w, self.v_b = [m.weight for m in v_lin], [m.bias for m in v_lin]
        self.log_std = policy.log_std if self.applies else torch.zeros(0)
        self.targets = [*self.pi_w, *self.pi_b, self.log_std, *self.v_w, *self.v_b]

    def __call__(self, x_pi: Tensor, x_v: Tensor, acts: Tensor, logp_old: Tensor, adv: Tensor, returns: Tensor,
                 x_anchor: Tensor, target: Tensor, clip: float, vf_coef: float, ent_coef: float,
                 anchor_coef: float) -> tuple[Tensor, Tensor]:
        with torch.no_grad():
            grads, parts, log_ratio = scripted(_minibatch_grads)(
                x_pi, x_v, acts, logp_old, adv, returns, x_anchor, target, self.pi_w, self.pi_b, self.log_std,
                self.v_w, self.v_b, clip, vf_coef, ent_coef, anchor_coef)
        for p, g in zip(self.targets, grads, strict=True):
            p.grad = g if p.requires_grad else None
        return parts, log_ratio
