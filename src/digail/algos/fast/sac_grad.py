"""The soft actor-critic's critic and policy gradients written out by hand, in TorchScript.

Why: one env step of SAC is one update, so a run makes a million of them, each a few dozen small tensor operations
whose dispatch and autograd bookkeeping cost more than the arithmetic with 64x64 nets; and autograd's policy step
would also compute the critics' weight gradients it then throws away. Here two scripted functions compute the
critics' loss and gradient (target included) and the policy's loss and gradient (back through the critics to the
action only): the same maths as `SACUpdate.update`'s autograd path, to float rounding (tests/test_sac.py checks
them against autograd in float64). `sac_update` runs a whole update in one call: both gradients, the three Adam
steps (torch's fused Adam kernel on the optimisers' own state, as `torch.optim.Adam(fused=True).step` calls it)
and the targets' Polyak step; `disc_update` does the same for D. Used for Gaussian policies whose executed action
is a clip to the bounds and without the BC term; the rest keeps the autograd path.
"""

from __future__ import annotations

import torch
from torch import Tensor

from digail.algos.fast import mlp
from digail.algos.fast.ops import adam_step, polyak, relu_backward


def _twin_forward(x: Tensor, w: list[Tensor], b: list[Tensor]) -> tuple[Tensor, list[Tensor]]:
    """`TwinQ.forward` on ready inputs x (B, in): values (2, B) and every layer's input (2, B, .)."""
    h = x.unsqueeze(0).expand(2, x.shape[0], x.shape[1])
    hs = [h]
    for i in range(len(w) - 1):
        h = torch.baddbmm(b[i], h, w[i]).relu_()
        hs.append(h)
    # the one-unit output layer as a product and a sum: a batched matmul with one output column takes several
    # times longer on the CPU (`_twin_out_grads` likewise)
    return (h * w[-1].transpose(1, 2)).sum(-1) + b[-1].squeeze(-1), hs


def _twin_out_input_grad(g: Tensor, w_out: Tensor) -> Tensor:
    """The gradient (2, B, H) at the output layer's input for the values' gradient g (2, B, 1)."""
    return g * w_out.transpose(1, 2)


def critic_grads(x: Tensor, x_next_pi: Tensor, next_obs_code: Tensor, noise_next: Tensor, terminated: Tensor,
                 rews: Tensor, v_abs: Tensor, alpha: Tensor, entropy: Tensor, gamma: float, low: Tensor, high: Tensor,
                 pi_w: list[Tensor], pi_b: list[Tensor], std: Tensor, q_w: list[Tensor], q_b: list[Tensor],
                 t_w: list[Tensor], t_b: list[Tensor]) -> tuple[list[Tensor], Tensor, Tensor]:
    """Gradients of the critics' loss 0.5 * sum_i mean (Q_i(s, c, a) - y)^2 for the inputs x = [s, c, a] (B, in).

    The target y = r + gamma * (terminated ? V_abs : min_i Q'_i(s', c', a') + alpha H) with a' = clip(mean + std *
    noise_next) of pi at its inputs `x_next_pi` (s', c'), and `next_obs_code` = [s', c'] (B, .) for the critics.
    Returns (weight gradients then bias gradients, loss, mean Q).
    """
    mean_next, _ = mlp.forward(x_next_pi, pi_w, pi_b)
    a_next = torch.minimum(torch.maximum(mean_next + std * noise_next, low), high)
    q_next, _ = _twin_forward(torch.cat([next_obs_code, a_next], -1), t_w, t_b)
    v_next = torch.where(terminated, v_abs, q_next.min(0)[0] + alpha * entropy)
    target = rews + v_next * gamma
    q, hs = _twin_forward(x, q_w, q_b)
    err = q - target
    B = x.shape[0]
    loss = (err * err).mean(1).sum() * 0.5
    g = (err * (1.0 / B)).unsqueeze(-1)  # (2, B, 1)
    g_w: list[Tensor] = []
    g_b: list[Tensor] = []
    last = len(q_w) - 1
    for i in range(last, -1, -1):
        g_w.append((hs[i] * g).sum(1).unsqueeze(-1) if i == last else torch.bmm(hs[i].transpose(1, 2), g))
        g_b.append(g.sum(1, keepdim=True))
        if i > 0:
            g_in = _twin_out_input_grad(g, q_w[i]) if i == last else torch.bmm(g, q_w[i].transpose(1, 2))
            g = relu_backward(g_in, hs[i])
    g_w.reverse()
    g_b.reverse()
    return g_w + g_b, loss, q.mean()


def policy_grads(x_pi: Tensor, obs_code: Tensor, noise: Tensor, alpha: Tensor, entropy: Tensor, low: Tensor,
                 high: Tensor, pi_w: list[Tensor], pi_b: list[Tensor], log_std: Tensor, q_w: list[Tensor],
                 q_b: list[Tensor]) -> tuple[list[Tensor], Tensor]:
    """Gradients of the policy's loss -mean_B min_i Q_i(s, c, clip(mean + std * noise)) - alpha H.

    `x_pi` are pi's inputs (B, .), `obs_code` = [s, c] the critics'. Only the action's gradient is taken back
    through the critics. Returns (pi's weight gradients, bias gradients, then log-std's; loss).
    """
    B = x_pi.shape[0]
    A = noise.shape[1]
    ls = log_std.clamp(-5.0, 2.0)
    std = ls.exp()
    mean, pi_xs = mlp.forward(x_pi, pi_w, pi_b)
    raw = mean + std * noise
    acts = torch.minimum(torch.maximum(raw, low), high)
    q, hs = _twin_forward(torch.cat([obs_code, acts], -1), q_w, q_b)
    q_min, which = q.min(0)
    loss = q_min.mean().neg() - alpha * entropy
    # d loss / d Q_i: -1/B on the smaller critic of each row (where torch's min puts the gradient), 0 on the other
    g = (torch.stack([which == 0, which == 1]).to(q.dtype) * (-1.0 / B)).unsqueeze(-1)
    last = len(q_w) - 1
    for i in range(last, 0, -1):
        g_in = _twin_out_input_grad(g, q_w[i]) if i == last else torch.bmm(g, q_w[i].transpose(1, 2))
        g = relu_backward(g_in, hs[i])
    w0 = q_w[0]
    w_act = w0[:, w0.shape[1] - A:, :]  # (2, A, H): the action's rows of the first layer
    # (B, A) as two plain matmuls: a batched one with A output columns is several times slower on the CPU
    g_act = g[0].mm(w_act[0].t()) + g[1].mm(w_act[1].t())
    g_raw = g_act * ((raw >= low) & (raw <= high)).to(raw.dtype)  # the clamp passes its gradient inside the bounds
    in_range = ((log_std >= -5.0) & (log_std <= 2.0)).to(log_std.dtype)
    g_log_std = ((g_raw * noise).sum(0) * std - alpha) * in_range
    g_pi_w, g_pi_b, _ = mlp.backward(g_raw, pi_xs, pi_w, False)
    return g_pi_w + g_pi_b + [g_log_std], loss


def fused_adam(params: list[Tensor], grads: list[Tensor], state: list[list[Tensor]], hyper: list[float]) -> None:
    """`torch.optim.Adam(fused=True).step` on its state [exp_avgs, exp_avg_sqs, steps] with hyper = [lr, beta1,
    beta2, eps]: the same two calls, so the same bits (`digail.algos.fast.step.FusedAdamState` supplies both).

    `params` is a list the caller was given, never one built in the scripted code (`a + b`, `[x]`): TorchScript
    dropped the foreach lerp (`polyak`) on such lists as if it had no effect (torch 2.13), so no in-place list
    operation here takes one."""
    adam_step(params, grads, state[0], state[1], state[2], hyper[0], hyper[1], hyper[2], hyper[3])


def sac_update(x: Tensor, x_next_pi: Tensor, next_obs_code: Tensor, x_pi: Tensor, obs_code: Tensor,
               noise_next: Tensor, noise_pi: Tensor, terminated: Tensor, rews: Tensor, v_abs: Tensor,
               gamma: float, tau: float, target_entropy: float, low: Tensor, high: Tensor, pi_params: list[Tensor],
               q_params: list[Tensor], t_params: list[Tensor], alpha_params: list[Tensor],
               q_adam: list[list[Tensor]], q_hyper: list[float], pi_adam: list[list[Tensor]], pi_hyper: list[float],
               alpha_adam: list[list[Tensor]], alpha_hyper: list[float], train_policy: bool,
               learn_alpha: bool) -> Tensor:
    """One whole SAC update in `SACUpdate.update`'s order: the critics' gradient and Adam step, the policy's
    gradient against the updated critics and its step (`train_policy`), the temperature's step (`learn_alpha` and
    `train_policy`), the targets' Polyak step with rate `tau`.

    Inputs as for `critic_grads` and `policy_grads`, with the parameters as lists: `pi_params` pi's weights, biases
    and log-std, `q_params` / `t_params` the critics' and the targets' weights then biases, `alpha_params`
    [log alpha]; `*_adam` / `*_hyper` the optimisers' state and settings (see `fused_adam`; unused ones may be
    empty). Returns [critic loss, policy loss, alpha loss, alpha, entropy, mean Q, 0 (no BC term)]."""
    log_2pi = 1.8378770664093453  # log(2 pi): TorchScript reads no module-level floats
    act_dim = noise_pi.shape[1]
    n_pi = (len(pi_params) - 1) // 2
    pi_w, pi_b, log_std = pi_params[:n_pi], pi_params[n_pi:2 * n_pi], pi_params[2 * n_pi]
    n_q = len(q_params) // 2
    q_w, q_b = q_params[:n_q], q_params[n_q:]
    log_alpha = alpha_params[0]
    alpha = log_alpha.exp()
    ls = log_std.clamp(-5.0, 2.0)
    entropy = ls.sum() + 0.5 * act_dim * (1.0 + log_2pi)
    q_grads, q_loss, q_mean = critic_grads(x, x_next_pi, next_obs_code, noise_next, terminated, rews, v_abs, alpha,
                                           entropy, gamma, low, high, pi_w, pi_b, ls.exp(), q_w, q_b,
                                           t_params[:n_q], t_params[n_q:])
    fused_adam(q_params, q_grads, q_adam, q_hyper)
    pi_grads, pi_loss = policy_grads(x_pi, obs_code, noise_pi, alpha, entropy, low, high, pi_w, pi_b, log_std,
                                     q_w, q_b)
    if train_policy:
        fused_adam(pi_params, pi_grads, pi_adam, pi_hyper)
    # the temperature's loss log_alpha (H - H_target), its gradient H - H_target (see `SACUpdate`)
    alpha_loss = log_alpha * (entropy - target_entropy)
    if learn_alpha and train_policy:
        fused_adam(alpha_params, [(entropy - target_entropy).reshape(())], alpha_adam, alpha_hyper)
    polyak(t_params, q_params, tau)
    return torch.stack([q_loss, pi_loss, alpha_loss, alpha, entropy, q_mean, torch.zeros_like(q_loss)])


def disc_grads(x_agent: Tensor, x_expert: Tensor, mix: Tensor, w: list[Tensor], b: list[Tensor],
               gp_weight: float) -> tuple[list[Tensor], Tensor]:
    """Gradients of D's loss: binary cross-entropy (agent rows `x_agent` labelled 0, expert rows 1) plus `gp_weight`
    times the gradient penalty mean((|d logit / d x| - 1)^2) on the rows `mix` (none when `mix` has no rows).

    For a ReLU MLP the input gradient is W_0^T m_0 W_1^T m_1 ... W_L^T with the ReLU masks m_i of the row, so the
    penalty's gradient is a second pass through the same weights (the biases only move the masks: no gradient).
    Returns (weight gradients then bias gradients; [loss, agent accuracy, expert accuracy, penalty]).
    """
    n_a = x_agent.shape[0]
    n_e = x_expert.shape[0]
    out, xs = mlp.forward(torch.cat([x_agent, x_expert]), w, b)
    logits = out.squeeze(-1)
    l_a, l_e = logits[:n_a], logits[n_a:]
    sp = torch.nn.functional.softplus
    loss = sp(l_a).mean() + sp(l_e.neg()).mean()
    g_out = torch.cat([torch.sigmoid(l_a) * (1.0 / n_a), torch.sigmoid(l_e.neg()) * (-1.0 / n_e)]).unsqueeze(-1)
    g_w, g_b, _ = mlp.backward(g_out, xs, w, False)
    penalty = loss.new_zeros(())
    n_m = mix.shape[0]
    if n_m > 0 and gp_weight > 0:
        L = len(w) - 1
        masks: list[Tensor] = []
        h = mix
        for i in range(L):
            z = torch.nn.functional.linear(h, w[i], b[i])
            masks.append((z > 0).to(mix.dtype))
            h = z.relu()
        # the input gradient, keeping every layer's t_i (the masked gradient at layer i's output)
        s = w[L].expand(n_m, w[L].shape[1])
        ts: list[Tensor] = []
        for i in range(L - 1, -1, -1):
            t = masks[i] * s
            ts.append(t)
            s = t.mm(w[i])
        ts.reverse()
        norm = torch.linalg.vector_norm(s, 2.0, [1])
        dev = norm - 1.0
        penalty = (dev * dev).mean()
        ds = s * (dev * 2.0 / (norm.clamp_min(1e-12) * n_m)).unsqueeze(-1) * gp_weight
        for i in range(L):
            g_w[i] = g_w[i] + ts[i].t().mm(ds)
            ds = ds.mm(w[i].t()) * masks[i]
        g_w[L] = g_w[L] + ds.sum(0, keepdim=True)
    parts = torch.stack([loss, (l_a < 0).to(loss.dtype).mean(),
                         (l_e > 0).to(loss.dtype).mean(), penalty])
    return g_w + g_b, parts


def disc_update(x_agent: Tensor, x_expert: Tensor, mix: Tensor, params: list[Tensor], gp_weight: float,
                adam: list[list[Tensor]], hyper: list[float]) -> Tensor:
    """`disc_grads` and D's Adam step (see `fused_adam`) in one call, `params` D's weights then biases; returns the
    parts."""
    n = len(params) // 2
    grads, parts = disc_grads(x_agent, x_expert, mix, params[:n], params[n:], gp_weight)
    fused_adam(params, grads, adam, hyper)
    return parts
