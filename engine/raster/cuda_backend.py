"""CUDA backend: gsplat 1.5.x ``rasterization`` behind the ``rasterize`` contract.

gsplat is an optional extra (installed ``--no-deps`` so it cannot pull another torch) and is
imported lazily. We call it with ``packed=False`` so its per-Gaussian outputs are dense (N, ...)
rows, and ``absgrad=False``: densification uses the plain screen-space gradient, which lands in
``meta["means2d"].grad`` after ``retain_grad()``. Colours are rendered as ``RGB+D`` (features plus
accumulated depth, not divided by alpha) or ``D`` alone when there are no feature channels.
"""

from __future__ import annotations

import torch
from torch import Tensor

from sparsesplat.engine.camera import Camera
from sparsesplat.engine.errors import RasterError
from sparsesplat.engine.raster.types import RasterOutput


def rasterize_gsplat(
    means: Tensor,
    log_scales: Tensor,
    quats: Tensor,
    opacity_logits: Tensor,
    features: Tensor,
    camera: Camera,
    background: Tensor,
    near: float,
    far: float,
    eps2d: float,
) -> RasterOutput:
    """Render CUDA tensors with gsplat (see ``rasterize`` for the contract)."""
    try:
        from gsplat import rasterization
    except ImportError as exc:
        raise RasterError(
            "backend='cuda' needs gsplat 1.5.x (pip install --no-deps gsplat==1.5.3): " + str(exc)
        ) from exc
    c = features.shape[1]
    dev, dtype = means.device, means.dtype
    viewmat = camera.world_to_camera.to(device=dev, dtype=dtype).unsqueeze(0)
    k = camera.K.to(device=dev, dtype=dtype).unsqueeze(0)
    if c > 0:
        colors, mode = features, "RGB+D"
        bg = torch.cat([background, background.new_zeros(1)]).unsqueeze(0)
    else:
        colors, mode = features.new_zeros(means.shape[0], 1), "D"
        bg = None
    renders, alphas, meta = rasterization(
        means=means,
        quats=quats,
        scales=torch.exp(log_scales),
        opacities=torch.sigmoid(opacity_logits),
        colors=colors,
        viewmats=viewmat,
        Ks=k,
        width=camera.width,
        height=camera.height,
        near_plane=near,
        far_plane=far,
        eps2d=eps2d,
        render_mode=mode,
        backgrounds=bg,
        packed=False,
        absgrad=False,
        rasterize_mode="classic",
    )
    out = renders[0].permute(2, 0, 1)  # (C + 1, H, W)
    means2d = meta["means2d"][0] if meta["means2d"].dim() == 3 else meta["means2d"]
    if torch.is_grad_enabled() and means2d.requires_grad:
        means2d.retain_grad()
    radii = (
        meta["radii"][0]
        if meta["radii"].dim() >= 2 and meta["radii"].shape[0] == 1
        else meta["radii"]
    )
    if radii.dim() == 2:  # gsplat >= 1.5: per-axis radii
        radii = radii.max(dim=-1).values
    return RasterOutput(
        image=out[:c],
        depth=out[c:],
        alpha=alphas[0].permute(2, 0, 1),
        radii=radii.to(torch.int32),
        means2d=means2d,
    )
