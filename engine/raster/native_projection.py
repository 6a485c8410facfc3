"""The native (C++) EWA projection: ``projection.project`` for float32 CPU tensors, fused.

``project_native`` returns the same :class:`~sparsesplat.engine.raster.projection.Projected` as
the torch function, with the same values to float32 rounding and the gradients of the same
graph, but as one kernel call each way instead of ~100 small torch ops (see
``engine/raster/cpu/project.cpp``). The backward computes only the gradients autograd asks for:
the soft-depth pass wants opacity logits only, the hard-depth pass means only.
"""

from __future__ import annotations

from typing import Any

import torch
from torch import Tensor

from sparsesplat.engine.camera import Camera
from sparsesplat.engine.raster.build import load_projection_extension
from sparsesplat.engine.raster.projection import Projected, view_frame


def camera_params(camera: Camera, near: float, far: float, eps2d: float) -> list[float]:
    """The kernel's camera vector: centre (float64), rotation (float32 values), intrinsics, range.

    The centre and rotation come from ``projection.view_frame``, as in ``projection.project``, so
    the kernel starts from bit-identical values: ``R (m - c)`` with ``c = -R^T t`` in float64.
    """
    rot64, centre64 = (t.detach() for t in view_frame(camera))
    rot32 = rot64.to(torch.float32).to(torch.float64)
    intrinsics = [float(camera.fx), float(camera.fy), float(camera.cx), float(camera.cy)]
    return [
        *centre64.tolist(),
        *rot32.reshape(-1).tolist(),
        *intrinsics,
        float(near),
        float(far),
        float(eps2d),
    ]


class _Project(torch.autograd.Function):
    """Forward and analytic backward of the projection, both in the C++ kernel."""

    @staticmethod
    def forward(
        ctx: Any,
        means: Tensor,
        log_scales: Tensor,
        quats: Tensor,
        opacity_logits: Tensor,
        params: list[float],
        width: int,
        height: int,
    ) -> tuple[Tensor, Tensor, Tensor, Tensor, Tensor]:
        ext = load_projection_extension()
        means2d, conics, depths, opacities, radii = ext.forward(
            means, log_scales, quats, opacity_logits, params, width, height
        )
        # The backward recomputes the per-Gaussian geometry from the inputs (cheaper than saving
        # it); the opacities are saved because the sigmoid's backward needs only them.
        ctx.save_for_backward(means, log_scales, quats, opacities)
        ctx.params, ctx.width, ctx.height = params, width, height
        # An output that depends on no input requiring grad must not require grad itself, as in
        # the torch graph: the blend's backward skips the 2D mean and conic gradients when they
        # do not (the soft-depth pass, where only the opacity logits train).
        g_m, g_s, g_q, g_o = ctx.needs_input_grad[:4]
        fixed = [radii]
        fixed += [] if g_m else [means2d, depths]
        fixed += [] if g_m or g_s or g_q else [conics]
        fixed += [] if g_o else [opacities]
        ctx.mark_non_differentiable(*fixed)
        return means2d, conics, depths, opacities, radii

    @staticmethod
    def backward(
        ctx: Any,
        v_means2d: Tensor,
        v_conics: Tensor,
        v_depths: Tensor,
        v_opacities: Tensor,
        _v_radii: Tensor,
    ) -> tuple[Tensor | None, ...]:
        means, log_scales, quats, opacities = ctx.saved_tensors
        need = [bool(f) for f in ctx.needs_input_grad[:4]]
        if not any(need):
            return None, None, None, None, None, None, None
        ext = load_projection_extension()
        g_means, g_scales, g_quats, g_logits = ext.backward(
            means, log_scales, quats, opacities, ctx.params, ctx.width, ctx.height,
            v_means2d.contiguous(), v_conics.contiguous(), v_depths.contiguous(),
            v_opacities.contiguous(), need,
        )  # fmt: skip
        # The kernel returns undefined tensors (None here) for the gradients it skipped.
        return g_means, g_scales, g_quats, g_logits, None, None, None


def project_native(
    means: Tensor,
    log_scales: Tensor,
    quats: Tensor,
    opacity_logits: Tensor,
    camera: Camera,
    near: float,
    far: float,
    eps2d: float,
) -> Projected:
    """``projection.project`` for float32 CPU tensors, as one fused kernel each way.

    Same arguments, outputs and gradients as the torch function (see its docstring); the inputs
    must already be validated (``rasterize`` does it). ``radii`` carries no gradient, and neither
    does the camera: its pose is read as a constant (nothing in sparsesplat optimizes poses).
    """
    params = camera_params(camera, near, far, eps2d)
    w, h = int(camera.width), int(camera.height)
    means2d, conics, depths, opacities, radii = _Project.apply(
        means.contiguous(), log_scales.contiguous(), quats.contiguous(),
        opacity_logits.contiguous(), params, w, h,
    )  # fmt: skip
    return Projected(means2d, conics, depths, opacities, radii)
