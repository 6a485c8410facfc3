"""CUDA backend: gsplat 1.5.x kernels behind the ``rasterize`` contract.

gsplat is an optional extra (installed ``--no-deps`` so it cannot pull another torch) and is
imported lazily. Its PyPI wheel holds no binaries: the first CUDA call JIT-compiles the kernels
with torch's ``cpp_extension`` (nvcc and ninja needed; a few minutes once, cached under
``$TORCH_EXTENSIONS_DIR``; ``TORCH_CUDA_ARCH_LIST`` and ``MAX_JOBS`` shorten it).

We call gsplat's three stages ourselves (``fully_fused_projection``, the tile intersection and
``rasterize_to_pixels``) rather than its ``rasterization`` wrapper, for two reasons:

* ``means2d``: the wrapper returns the projected centres as a (1, N, 2) tensor; a view ``[0]``
  taken afterwards is not on the path to the loss, so its ``.grad`` stays None and
  densification silently sees no gradient. Here the (N, 2) row *is* what the rasteriser
  consumes, so ``retain_grad()`` on it yields the screen-space gradient.
* background and depth: we append the depth channel (``sum w_i z_i``, not divided by alpha) and
  its zero background ourselves, exactly once.

Projection is dense (``packed=False``), classic (no anti-aliasing compensation), with
gsplat's opacity-aware screen extents, as the reference in ``raster/reference.py`` restates.
"""

from __future__ import annotations

import math
from types import ModuleType

import torch
from torch import Tensor

from sparsesplat.engine.camera import Camera
from sparsesplat.engine.errors import RasterError
from sparsesplat.engine.raster.types import RasterInputs, RasterOutput

TILE_SIZE = 16
"""Tile edge in pixels (gsplat's default)."""
GSPLAT_HINT = "pip install --no-deps gsplat==1.5.3 (plus ninja, jaxtyping, rich, packaging)"
"""How to install the CUDA backend's dependency (see docker/Dockerfile.cuda)."""


def _gsplat() -> ModuleType:
    """gsplat with its CUDA extension loaded (compiled on first use); RasterError otherwise."""
    try:
        import gsplat
    except ImportError as exc:
        raise RasterError(f"backend='cuda' needs gsplat 1.5.x ({GSPLAT_HINT}): {exc}") from exc
    try:
        from gsplat.cuda._backend import _C
    except Exception as exc:  # a failed JIT build raises RuntimeError/OSError/ImportError
        raise RasterError(
            f"backend='cuda': gsplat {getattr(gsplat, '__version__', '?')} could not build or "
            f"load its CUDA extension (needs nvcc matching torch's CUDA, ninja and a C++ "
            f"compiler): {type(exc).__name__}: {exc}"
        ) from exc
    if _C is None:  # gsplat found no CUDA toolkit and disabled itself
        raise RasterError(
            "backend='cuda': gsplat found no CUDA toolkit (nvcc) to compile its kernels; "
            "install the CUDA toolkit matching torch's CUDA or set CUDA_HOME"
        )
    return gsplat


def rasterize_gsplat(args: RasterInputs) -> RasterOutput:
    """Render float32 CUDA tensors with gsplat (see ``rasterize`` for the contract)."""
    means, log_scales, quats, opacity_logits, features, camera, background, near, far, eps2d = args
    if means.dtype != torch.float32:
        raise RasterError(
            f"means: gsplat renders float32, got {means.dtype} (use backend='reference')"
        )
    gs = _gsplat()
    n, c = means.shape[0], features.shape[1]
    dev = means.device
    width, height = int(camera.width), int(camera.height)
    if n == 0:
        # gsplat's projection divides by N: no Gaussians kills the process with SIGFPE.
        return _empty(means, log_scales, quats, opacity_logits, features, background, camera)
    viewmats = camera.world_to_camera.to(device=dev, dtype=torch.float32).reshape(1, 4, 4)
    ks = camera.K.to(device=dev, dtype=torch.float32).reshape(1, 3, 3)
    opacities = torch.sigmoid(opacity_logits)
    radii_c, means2d_c, depths_c, conics_c, _ = gs.fully_fused_projection(
        means.contiguous(),
        None,
        quats.contiguous(),
        torch.exp(log_scales).contiguous(),
        viewmats.contiguous(),
        ks.contiguous(),
        width,
        height,
        eps2d=eps2d,
        near_plane=near,
        far_plane=far,
        packed=False,
        calc_compensations=False,
        opacities=opacities.detach().contiguous(),
    )
    # (N, 2): the tensor the rasteriser consumes below, so its .grad is the screen gradient.
    means2d = means2d_c[0]
    if torch.is_grad_enabled() and means2d.requires_grad:
        means2d.retain_grad()
    depths = depths_c[0]
    colors = torch.cat([features, depths.unsqueeze(-1)], dim=-1)  # depth as the last channel
    bg = None
    if c > 0:
        bg = torch.cat([background.to(torch.float32), background.new_zeros(1)]).unsqueeze(0)
    tiles_w, tiles_h = math.ceil(width / TILE_SIZE), math.ceil(height / TILE_SIZE)
    with torch.no_grad():
        _, isect_ids, flatten_ids = gs.isect_tiles(
            means2d_c.detach(),
            radii_c,
            depths_c.detach(),
            TILE_SIZE,
            tiles_w,
            tiles_h,
            packed=False,
            n_images=1,
        )
        offsets = gs.isect_offset_encode(isect_ids, 1, tiles_w, tiles_h)
    renders, alphas = gs.rasterize_to_pixels(
        means2d.unsqueeze(0),
        conics_c,
        colors.unsqueeze(0).contiguous(),
        opacities.unsqueeze(0).contiguous(),
        width,
        height,
        TILE_SIZE,
        offsets.reshape(1, tiles_h, tiles_w),
        flatten_ids,
        backgrounds=bg,
        packed=False,
    )
    out = renders[0].permute(2, 0, 1)  # (C + 1, H, W)
    radii = radii_c[0]
    if radii.dim() == 2:  # gsplat >= 1.5: per-axis radii
        radii = radii.amax(dim=-1)
    assert radii.shape == (n,)
    return RasterOutput(
        image=out[:c],
        depth=out[c:],
        alpha=alphas[0].permute(2, 0, 1),
        radii=radii.to(torch.int32),
        means2d=means2d,
    )


def _empty(
    means: Tensor,
    log_scales: Tensor,
    quats: Tensor,
    opacity_logits: Tensor,
    features: Tensor,
    background: Tensor,
    camera: Camera,
) -> RasterOutput:
    """The render of zero Gaussians: the background, zero depth and alpha. The outputs stay in
    the inputs' autograd graph (zero, empty gradients), so a backward works as for N > 0."""
    h, w = int(camera.height), int(camera.width)
    inputs = (means, log_scales, quats, opacity_logits, features)
    anchor = sum((t.sum() for t in inputs), means.new_zeros(())) * 0.0
    image = background.reshape(-1, 1, 1).expand(-1, h, w) + anchor
    zeros = means.new_zeros(1, h, w) + anchor
    means2d = means[:, :2] * 0.0
    if torch.is_grad_enabled() and means2d.requires_grad:
        means2d.retain_grad()
    radii = torch.zeros(0, dtype=torch.int32, device=means.device)
    return RasterOutput(image=image, depth=zeros, alpha=zeros.clone(), radii=radii, means2d=means2d)
