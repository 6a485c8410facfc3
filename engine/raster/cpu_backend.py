"""Native CPU backend (temporary dense float32 path until the C++ kernel lands)."""

from __future__ import annotations

from torch import Tensor

from sparsesplat.engine.camera import Camera
from sparsesplat.engine.raster.types import RasterOutput


def rasterize_cpu(
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
    """Render on the CPU (float32)."""
    import torch

    from sparsesplat.engine.raster.reference import rasterize_reference

    return rasterize_reference(
        means, log_scales, quats, opacity_logits, features, camera, background, near, far,
        eps2d, dtype=torch.float32,
    )  # fmt: skip
