"""Types shared by every rasterizer backend."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, NamedTuple

from torch import Tensor

from sparsesplat.engine.camera import Camera


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


class RasterInputs(NamedTuple):
    """The checked arguments of one render, as ``rasterize`` hands them to a backend.

    Each field means what the argument of the same name means in ``rasterize`` (its docstring
    is the contract); ``background`` is always a (C,) tensor here, never None.
    """

    means: Tensor
    """(N, 3) world-space centres."""
    log_scales: Tensor
    """(N, 3) log standard deviations along the Gaussian's own axes."""
    quats: Tensor
    """(N, 4) wxyz rotations."""
    opacity_logits: Tensor
    """(N,) opacities before the sigmoid."""
    features: Tensor
    """(N, C) per-Gaussian features blended into the image."""
    camera: Camera
    """Pose and intrinsics."""
    background: Tensor
    """(C,) blended in as ``(1 - alpha) * background``."""
    near: float
    """View-space z below which centres are culled."""
    far: float
    """View-space z above which centres are culled."""
    eps2d: float
    """Low-pass dilation added to the 2D covariance diagonal (pixels^2)."""
