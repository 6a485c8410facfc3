"""A model's colours as degree-3 SH: the one bake (for the .ply/.splat exports and the
``baked`` render mode) and how faithful it is."""

from __future__ import annotations

import torch
from torch import Tensor

from sparsesplat.engine.camera import Camera
from sparsesplat.engine.color.models import ColorModel, NeuralColor, SHColor
from sparsesplat.engine.export import bake_sh, sh_baking_error
from sparsesplat.engine.gaussians import Gaussians

BAKE_DEGREE = 3
"""SH degree neural colours are baked to (the most the 3DGS formats hold)."""


def model_sh(gaussians: Gaussians, color: ColorModel, cameras: list[Camera]) -> Tensor:
    """(N, K, 3) SH coefficients of the model (float32, CPU): exact for SH colour; for neural
    colour a degree-3 least-squares bake over sphere directions plus, when ``cameras`` are
    given, the directions from them to each Gaussian (the training views: the bake is then
    most faithful where the model was trained)."""
    if isinstance(color, SHColor):
        dc = gaussians.params["sh_dc"].detach().cpu()
        if "sh_rest" in gaussians.params:
            return torch.cat([dc, gaussians.params["sh_rest"].detach().cpu()], dim=1)
        return dc
    means = gaussians.means.detach()
    view_dirs = None
    if cameras:
        centers = torch.stack([c.center.to(means) for c in cameras])
        view_dirs = torch.nn.functional.normalize(means[:, None, :] - centers[None], dim=-1)
        view_dirs = view_dirs.cpu()
    return bake_sh(
        color.color_fn(gaussians),
        len(gaussians),
        degree=BAKE_DEGREE,
        view_dirs=view_dirs,
        device=means.device,
    )


def baking_psnr(
    g: Gaussians, color: NeuralColor, sh: Tensor, cameras: list[Camera], background: Tensor
) -> float:
    """PSNR of the SH-baked model's renders against the neural model's, over ``cameras``."""
    geo = color.geo_features(g)
    means = g.means.detach()

    def neural(cam: Camera) -> Tensor:
        return color.colors_cached(geo, means, cam.center.to(means)).cpu()

    return float(
        sh_baking_error(
            means.cpu(),
            g.log_scales.detach().cpu(),
            g.quats.detach().cpu(),
            g.opacity_logits.detach().cpu(),
            sh,
            neural,
            [c.to("cpu") for c in cameras],
            background.cpu(),
        )
    )
