"""Types shared by every rasterizer backend."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

from torch import Tensor


@dataclass
class RasterOutput:
    """What one render of a set of Gaussians through one camera returns."""

    image: Tensor
    """(C, H, W) alpha-blended features, background blended in as ``(1 - alpha) * background``."""
    depth: Tensor
    """(1, H, W) alpha-blended view-space z of the Gaussian centres, NOT divided by alpha."""
    alpha: Tensor
    """(1, H, W) accumulated opacity."""
    radii: Tensor
    """(N,) int32 screen-space radius in pixels; 0 where the Gaussian was culled."""
    means2d: Tensor
    """(N, 2) projected centres in pixels. When gradients are enabled it is part of the graph and
    has ``retain_grad()`` set, so after ``backward()`` its ``.grad`` holds the screen-space
    gradient that densification accumulates."""
    stats: dict[str, Any] | None = None
    """Backend counters when available (CPU: ``pairs_evaluated``, ``pairs_blended``), else None."""
    opacity_depth: Tensor | None = None
    """(1, H, W) the same values as ``depth``, whose gradient reaches the opacities only (the
    centres, scales, rotations and features see none of it): DNGaussian's soft-depth term
    computed on the photometric render instead of a second one. Set by ``rasterize(...,
    opacity_depth=True)`` when gradients are enabled; None otherwise."""
