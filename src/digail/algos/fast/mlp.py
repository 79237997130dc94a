"""The ReLU MLP's forward and backward pass for the hand-written gradients, written once.

`digail.nets.mlp.mlp` (Linear, ReLU, ..., Linear) as bare operations on its weight and bias lists: `forward` keeps
every layer's input, `backward` turns the output's gradient into the weights' and biases' gradients. Plain enough
for TorchScript, so the scripted gradients (`ppo_grad`, `sac_grad`, `vae_grad`, `polish_grad`) call them directly;
the kernels are autograd's own, in its order, so a gradient built from them matches autograd's to float rounding.
"""

from __future__ import annotations

import torch.nn.functional as F
from torch import Tensor, nn

from digail.algos.fast.ops import relu_backward


def forward(x: Tensor, w: list[Tensor], b: list[Tensor]) -> tuple[Tensor, list[Tensor]]:
    """The MLP's output for the 2-D inputs x, and every layer's input (x first; `backward` needs them)."""
    xs = [x]
    for i in range(len(w) - 1):
        xs.append(F.linear(xs[-1], w[i], b[i]).relu_())
    return F.linear(xs[-1], w[-1], b[-1]), xs


def output(x: Tensor, w: list[Tensor], b: list[Tensor]) -> Tensor:
    """The MLP's output alone (e.g. D's logits when relabelling a batch)."""
    return forward(x, w, b)[0]


def backward(g: Tensor, xs: list[Tensor], w: list[Tensor], thin: bool) -> tuple[list[Tensor], list[Tensor], Tensor]:
    """The weights' and biases' gradients for the output gradient `g` of `forward` (layer inputs `xs`), and the
    gradient at the first layer's output (for a caller that takes it back into part of the input).

    `thin`: each weight gradient as (x^T g)^T instead of g^T x, several times faster with MKL for the thousands of
    rows of a VAE batch (measured); g^T x is faster at a PPO or SAC minibatch's row counts. Both are contiguous (the
    fused Adam kernel reads the gradient's memory)."""
    g_w: list[Tensor] = []
    g_b: list[Tensor] = []
    for i in range(len(w) - 1, -1, -1):
        g_w.append(xs[i].t().mm(g).t().contiguous() if thin else g.t().mm(xs[i]))
        g_b.append(g.sum(0))
        if i > 0:  # ReLU's backward: the gradient passes where the layer's output is positive
            g = relu_backward(g.mm(w[i]), xs[i])
    g_w.reverse()
    g_b.reverse()
    return g_w, g_b, g


def plain_layers(seq: nn.Module) -> list[nn.Linear] | None:
    """The linear layers of a `mlp` (Linear, ReLU, ..., Linear; a lone Linear too), or None for anything else (the
    hand-written gradients cover only these)."""
    mods = list(seq) if isinstance(seq, nn.Sequential) else [seq]
    linears = mods[0::2]
    if not all(type(m) is nn.Linear and m.bias is not None for m in linears) or len(mods) % 2 == 0:
        return None
    if not all(type(m) is nn.ReLU for m in mods[1::2]):
        return None
    return linears  # type: ignore[return-value]
