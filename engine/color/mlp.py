"""The neural colour field's MLPs (training path) as one autograd function.

colour = act(relu(sh @ Wd^T + relu(relu(code @ W0^T) @ W1^T) @ M^T) @ W2^T), with
act(h) = sigmoid(h) * scale - shift and M the merged 64x64 product of the colour head's geometry
columns and the sigma MLP's output rows (see ``neural.py``). The same products autograd would
run, but each ReLU is applied in place and its backward masks the incoming gradient in place:
at tens of thousands of Gaussians the (N, 64) activations are ~13 MB each, and the separate
ReLU, threshold-backward and allocation passes autograd makes over them cost as much as a
third of the matrix products.
"""

from __future__ import annotations

from typing import Any

import torch
from torch import Tensor
from torch.autograd.function import once_differentiable


def _relu_backward_(grad: Tensor, activation: Tensor) -> Tensor:
    """grad * (activation > 0), written into ``grad``."""
    return torch.ops.aten.threshold_backward.grad_input(grad, activation, 0.0, grad_input=grad)


class ColorMLP(torch.autograd.Function):
    """``ColorMLP.apply(code, sh, w0, w1, merged, w_dir, w2, scale, shift)``: (N, 3) colours from
    the (N, levels*features) grid code and the (N, 16) direction code, weights as ``nn.Linear``
    stores them (out, in); differentiable in every tensor argument."""

    @staticmethod
    def forward(
        ctx: Any,
        code: Tensor,
        sh: Tensor,
        w0: Tensor,
        w1: Tensor,
        merged: Tensor,
        w_dir: Tensor,
        w2: Tensor,
        scale: float,
        shift: float,
    ) -> Tensor:
        h1 = torch.relu_(code @ w0.t())
        h2 = torch.relu_(h1 @ w1.t())
        # In place: an out-of-place addmm would first copy its (N, 64) input.
        h3 = torch.relu_((sh @ w_dir.t()).addmm_(h2, merged.t()))
        s = torch.sigmoid(h3 @ w2.t())
        ctx.save_for_backward(code, sh, w0, w1, merged, w_dir, w2, h1, h2, h3, s)
        ctx.scale = scale
        return s * scale - shift

    @staticmethod
    @once_differentiable
    def backward(ctx: Any, grad: Tensor) -> tuple[Tensor | None, ...]:
        code, sh, w0, w1, merged, w_dir, w2, h1, h2, h3, s = ctx.saved_tensors
        need = ctx.needs_input_grad
        g_o = grad * ctx.scale * s * (1 - s)
        g_w2 = g_o.t() @ h3 if need[6] else None
        g_pre = _relu_backward_(g_o @ w2, h3)
        g_merged = g_pre.t() @ h2 if need[4] else None
        g_wdir = g_pre.t() @ sh if need[5] else None
        g_sh = g_pre @ w_dir if need[1] else None
        g_h2 = _relu_backward_(g_pre @ merged, h2)
        g_w1 = g_h2.t() @ h1 if need[3] else None
        g_h1 = _relu_backward_(g_h2 @ w1, h1)
        g_w0 = g_h1.t() @ code if need[2] else None
        g_code = g_h1 @ w0 if need[0] else None
        return g_code, g_sh, g_w0, g_w1, g_merged, g_wdir, g_w2, None, None
