"""Rendering a model without gradients: the one render wrapper every caller goes through (the
trainer's evaluation and its ``render``, a loaded model's ``render``)."""

from __future__ import annotations

from collections.abc import Callable

import torch
from torch import Tensor

from sparsesplat.engine.camera import Camera
from sparsesplat.engine.color.models import ColorModel, NeuralColor
from sparsesplat.engine.gaussians import Gaussians
from sparsesplat.engine.model.raster import Raster
from sparsesplat.engine.raster import RasterOutput

ViewColors = Callable[[Tensor], Tensor]
"""``colors(camera_center)`` (3,) -> (N, 3) RGB of every Gaussian seen from there."""


def view_colors(color: ColorModel, gaussians: Gaussians, geo: Tensor | None = None) -> ViewColors:
    """The per-view colours of ``color`` on ``gaussians`` as the trainer evaluates them: the
    neural field with its geometry features computed once (``geo`` when given), an SH model
    through its own coefficients."""
    if isinstance(color, NeuralColor):
        if geo is None:
            with torch.no_grad():
                geo = color.geo_features(gaussians)
        features = geo
        return lambda center: color.colors_cached(features, gaussians.means, center)
    return lambda center: color.colors(gaussians, center)


def render_view(
    gaussians: Gaussians,
    colors: ViewColors,
    camera: Camera,
    background: Tensor,
    raster: Raster,
) -> RasterOutput:
    """Render ``gaussians`` coloured by ``colors`` through ``camera`` (on their device) onto
    ``background`` (3,), without gradients: (3, H, W) image, depth and alpha."""
    g = gaussians
    with torch.no_grad():
        feats = colors(camera.center.to(g.means))
        return raster(
            g.means, g.log_scales, g.quats, g.opacity_logits, feats, camera, background.to(g.means)
        )
