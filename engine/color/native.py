"""Autograd wrappers of the native CPU colour-field kernels (engine/color/cpu/).

Hash grid: the forward saves the inputs, the table and, when the inputs need a gradient, the
Jacobian d out / d x (levels, N, features, 3) it computes from the rows it gathers anyway; the
backward recomputes the corner indices and weights (cheap next to the memory traffic), scatters
the dense table gradient and contracts the upstream gradient with the Jacobian, each only when
autograd asks for it. SH: the 16-value direction encoding and its
analytic gradient, each one fused pass. MLPs: the colour field's two MLPs forward and backward,
block by block (cpu/mlp_kernels.h), saving the activations their backward needs.
"""

from __future__ import annotations

from typing import Any

import torch
from torch import Tensor
from torch.autograd.function import once_differentiable

from sparsesplat.engine.color.build import load_extension

Layout = tuple[list[float], list[int], list[int], list[int], list[bool]]
"""(scales, sizes, dense strides, offsets incl. the total, dense flags) per level."""


class _Encode(torch.autograd.Function):
    @staticmethod
    def forward(ctx: Any, x: Tensor, table: Tensor, layout: Layout) -> Tensor:
        ext = load_extension()
        # Training asks for the position gradient: the forward then also writes d out / d x
        # from the rows it gathers anyway, and the backward needs no second gather for it.
        need_jac = bool(ctx.needs_input_grad[0])
        out, jac = ext.forward(x, table, *layout, need_jac)
        ctx.save_for_backward(x, table, jac)
        ctx.layout = layout
        return out

    @staticmethod
    @once_differentiable
    def backward(ctx: Any, grad: Tensor) -> tuple[Tensor | None, Tensor | None, None]:
        x, table, jac = ctx.saved_tensors
        need_x, need_table = ctx.needs_input_grad[0], ctx.needs_input_grad[1]
        if not (need_x or need_table):
            return None, None, None
        ext = load_extension()
        gx, gt = ext.backward(
            x, table, grad.contiguous(), *ctx.layout, bool(need_x), bool(need_table), jac
        )
        return gx, gt, None


def encode_native(x: Tensor, table: Tensor, layout: Layout) -> Tensor:
    """(N, 3) float32 CPU points → (N, levels * features) with the native kernels."""
    return _Encode.apply(x.contiguous(), table.contiguous(), layout)


class _SH16(torch.autograd.Function):
    @staticmethod
    def forward(ctx: Any, dirs: Tensor) -> Tensor:
        ctx.save_for_backward(dirs)
        return load_extension().sh16_forward(dirs)

    @staticmethod
    @once_differentiable
    def backward(ctx: Any, grad: Tensor) -> Tensor:
        (dirs,) = ctx.saved_tensors
        return load_extension().sh16_backward(dirs, grad.contiguous())


def sh16_native(dirs: Tensor) -> Tensor:
    """(N, 3) float32 CPU unit directions → (N, 16) degree-3 real SH basis (as ``sh_basis``)."""
    return _SH16.apply(dirs.contiguous())


class NativeColorMLP(torch.autograd.Function):
    """``NativeColorMLP.apply`` takes and returns what ``mlp.ColorMLP.apply`` does (float32 CPU,
    hidden width 64, code width 16, 32 or 64) and runs the fused native kernels: each block of
    64 points goes through every layer, forward and backward, in cache."""

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
        weights = [w.contiguous() for w in (w0, w1, merged, w_dir, w2)]
        code, sh = code.contiguous(), sh.contiguous()
        out, h1, h2, h3, s = load_extension().mlp_forward(code, sh, *weights, scale, shift)
        ctx.save_for_backward(code, sh, *weights, h1, h2, h3, s)
        ctx.scale = scale
        return out

    @staticmethod
    @once_differentiable
    def backward(ctx: Any, grad: Tensor) -> tuple[Tensor | None, ...]:
        grads = load_extension().mlp_backward(grad.contiguous(), list(ctx.saved_tensors), ctx.scale)
        need = ctx.needs_input_grad
        return (*(g if need[i] else None for i, g in enumerate(grads)), None, None)
