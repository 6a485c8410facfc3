"""Dense pure-PyTorch rasterizer: the oracle the fast backends are tested against.

Every (pixel, Gaussian) pair is evaluated, so it is O(pixels x N): small scenes only. It runs in
float64 by default and differentiates through plain autograd. Compositing restates gsplat's rules:
front-to-back in depth order (ties by index), ``alpha = min(0.999, o exp(-power))``, pairs with
``power < 0`` or ``alpha < 1/255`` skipped, and a pixel stops *before* the Gaussian that would
take its transmittance to 1e-4 or below.
"""

from __future__ import annotations

import torch
from torch import Tensor

from sparsesplat.engine.raster.projection import ALPHA_THRESHOLD, Projected, project
from sparsesplat.engine.raster.types import RasterInputs, RasterOutput

MAX_ALPHA = 0.999
"""Alpha clamp (gsplat)."""
MIN_TRANSMITTANCE = 1e-4
"""A pixel stops before its transmittance would fall to this value (gsplat)."""
_PAIRS_PER_CHUNK = 1 << 21


def composite_dense(
    proj: Projected, features: Tensor, background: Tensor, width: int, height: int
) -> tuple[Tensor, Tensor, Tensor]:
    """Blend projected Gaussians densely; returns image (C,H,W), depth (1,H,W), alpha (1,H,W)."""
    dtype, device = proj.means2d.dtype, proj.means2d.device
    c = features.shape[1]
    keep = (proj.radii > 0).all(dim=-1)
    idx = torch.nonzero(keep).squeeze(-1)
    # Stable sort: equal depths keep index order, like gsplat's radix sort.
    order = idx[torch.sort(proj.depths.detach()[idx], stable=True).indices]
    m2d, con = proj.means2d[order], proj.conics[order]
    dep, opa = proj.depths[order], proj.opacities[order]
    feat = torch.cat([features[order], dep.unsqueeze(-1)], dim=-1)  # depth as an extra channel

    vv, uu = torch.meshgrid(
        torch.arange(height, device=device, dtype=dtype) + 0.5,
        torch.arange(width, device=device, dtype=dtype) + 0.5,
        indexing="ij",
    )
    px, py = uu.reshape(-1), vv.reshape(-1)
    n = order.numel()
    chunk = max(1, _PAIRS_PER_CHUNK // max(n, 1))
    outs, alphas = [], []
    for s in range(0, px.numel(), chunk):
        dx = m2d[:, 0].unsqueeze(0) - px[s : s + chunk].unsqueeze(1)
        dy = m2d[:, 1].unsqueeze(0) - py[s : s + chunk].unsqueeze(1)
        power = 0.5 * (con[:, 0] * dx * dx + con[:, 2] * dy * dy) + con[:, 1] * dx * dy
        alpha = torch.clamp(opa * torch.exp(-power), max=MAX_ALPHA)
        used = (power >= 0) & (alpha >= ALPHA_THRESHOLD)
        a = torch.where(used, alpha, torch.zeros_like(alpha))
        t_incl = torch.cumprod(1 - a, dim=1)
        stopped = torch.cumsum((used & (t_incl <= MIN_TRANSMITTANCE)).to(torch.int32), dim=1) > 0
        ones = torch.ones_like(t_incl[:, :1])
        t_excl = torch.cat([ones, t_incl[:, :-1]], dim=1)
        w = torch.where(used & ~stopped, a * t_excl, torch.zeros_like(a))
        outs.append(w @ feat)
        alphas.append(w.sum(dim=1))
    out = torch.cat(outs, 0) if outs else torch.zeros(0, c + 1, dtype=dtype, device=device)
    acc = torch.cat(alphas, 0) if alphas else torch.zeros(0, dtype=dtype, device=device)
    out = out.T.reshape(c + 1, height, width)
    alpha_img = acc.reshape(1, height, width)
    image = out[:c] + (1 - alpha_img) * background.reshape(c, 1, 1)
    return image, out[c:], alpha_img


def rasterize_reference(args: RasterInputs, dtype: torch.dtype = torch.float64) -> RasterOutput:
    """Project and composite densely in ``dtype``; outputs are cast back to the input dtype."""
    means, log_scales, quats, opacity_logits, features, camera, background, near, far, eps2d = args
    in_dtype = means.dtype
    proj = project(
        means.to(dtype),
        log_scales.to(dtype),
        quats.to(dtype),
        opacity_logits.to(dtype),
        camera,
        near,
        far,
        eps2d,
    )
    means2d = proj.means2d
    if torch.is_grad_enabled() and means2d.requires_grad:
        means2d.retain_grad()
    image, depth, alpha = composite_dense(
        proj, features.to(dtype), background.to(dtype), camera.width, camera.height
    )
    radii = proj.radii.max(dim=-1).values.to(torch.int32)
    return RasterOutput(image.to(in_dtype), depth.to(in_dtype), alpha.to(in_dtype), radii, means2d)
