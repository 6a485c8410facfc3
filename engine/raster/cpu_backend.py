"""Native CPU backend: the fused C++ projection and the C++/OpenMP tile kernel, both with analytic
backwards."""

from __future__ import annotations

from typing import Any

import torch
from torch import Tensor

from sparsesplat.engine.raster.build import (
    load_extension,
    load_extension_or_none,
    load_projection_extension_or_none,
)
from sparsesplat.engine.raster.native_projection import project_native
from sparsesplat.engine.raster.projection import project
from sparsesplat.engine.raster.reference import rasterize_reference
from sparsesplat.engine.raster.types import RasterInputs, RasterOutput


class _Blend(torch.autograd.Function):
    """Blending of projected 2D Gaussians; the backward is the kernel's analytic gradient."""

    @staticmethod
    def forward(
        ctx: Any,
        means2d: Tensor,
        conics: Tensor,
        opacities: Tensor,
        depths: Tensor,
        features: Tensor,
        background: Tensor,
        radii: Tensor,
        width: int,
        height: int,
    ) -> tuple[Tensor, Tensor, Tensor, Tensor, Tensor]:
        ext = load_extension()
        out = ext.forward(
            means2d, conics, opacities, depths, radii, features, background, width, height, True
        )
        image, depth, alpha, stats = out[:4]
        ctx.save_for_backward(background, *out[4:])
        ctx.n = means2d.shape[0]
        ctx.mark_non_differentiable(stats)
        # The same depth values as a second output, so a loss on it gets a gradient of its own
        # that the kernel routes to the opacities only (see RasterOutput.opacity_depth).
        return image, depth, alpha, stats, depth.clone()

    @staticmethod
    def backward(
        ctx: Any,
        v_image: Tensor,
        v_depth: Tensor,
        v_alpha: Tensor,
        _v_stats: Tensor,
        v_depth_opacity: Tensor | None,
    ) -> tuple[Tensor | None, ...]:
        background, recs, feats, rank, offsets, lists, t_final, last = ctx.saved_tensors
        ext = load_extension()
        # The soft-depth pass trains opacities only: skip the 2D mean and conic gradients.
        geometry = ctx.needs_input_grad[0] or ctx.needs_input_grad[1]
        v_dop = None if v_depth_opacity is None else v_depth_opacity.contiguous()
        v_m2, v_con, v_op, v_dep, v_feat = ext.backward(
            recs, feats, rank, offsets, lists, t_final, last, background,
            v_image.contiguous(), v_depth.contiguous(), v_alpha.contiguous(), v_dop, ctx.n,
            geometry,
        )  # fmt: skip
        if not geometry:
            v_m2 = v_con = None
        v_bg = None
        if ctx.needs_input_grad[5]:
            v_bg = (v_image * t_final.unsqueeze(0)).sum(dim=(1, 2))
        return v_m2, v_con, v_op, v_dep, v_feat, v_bg, None, None, None


def rasterize_cpu(args: RasterInputs) -> RasterOutput:
    """Render float32 CPU tensors with the native kernel (see ``rasterize`` for the contract).

    Where the native kernels cannot be built (a CPU or compiler they do not support), the torch
    implementations stand in, after one warning naming the slowdown (see ``build.py``): the
    dense reference rasterizer in float32 for the tile kernels, the torch projection for the
    projection kernel."""
    means, log_scales, quats, opacity_logits, features, camera, background, near, far, eps2d = args
    ext = load_extension_or_none()  # build/load before any work
    if ext is None:
        return rasterize_reference(args, dtype=torch.float32)
    projector = project_native if load_projection_extension_or_none() is not None else project
    proj = projector(means, log_scales, quats, opacity_logits, camera, near, far, eps2d)
    w, h = camera.width, camera.height
    radii = proj.radii.contiguous()
    tensors = (proj.means2d, proj.conics, proj.opacities, proj.depths, features, background)
    needs_grad = torch.is_grad_enabled() and any(t.requires_grad for t in tensors)
    opacity_depth = None
    if needs_grad:
        proj.means2d.retain_grad() if proj.means2d.requires_grad else None
        parts = [t.contiguous() for t in tensors]
        image, depth, alpha, stats, opacity_depth = _Blend.apply(*parts, radii, w, h)
    else:
        # Forward only: the kernel keeps no backward state (no T_final / last-index buffers).
        parts = [t.detach().contiguous() for t in tensors]
        image, depth, alpha, stats = ext.forward(*parts[:4], radii, *parts[4:], w, h, False)[:4]
    return RasterOutput(
        image=image,
        depth=depth,
        alpha=alpha,
        radii=radii.max(dim=-1).values.to(torch.int32),
        means2d=proj.means2d,
        stats={"pairs_evaluated": int(stats[0]), "pairs_blended": int(stats[1])},
        opacity_depth=opacity_depth,
    )
