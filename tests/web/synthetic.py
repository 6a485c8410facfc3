"""A synthetic splat model for the viewer's frame-rate measurement."""

from __future__ import annotations

import math
from pathlib import Path

import torch

from sparsesplat.engine.export.ply import export_ply


def write_synthetic_ply(path: Path, n: int = 50_000, seed: int = 0, radius: float = 0.8) -> Path:
    """``n`` small opaque Gaussians (SH degree 3) on a torus and a sphere of about ``radius``
    around the origin, the size of a Blender scene's object: what a trained object model's
    export looks like to a viewer (small splats, little overdraw), at a chosen count."""
    g = torch.Generator().manual_seed(seed)
    half = n // 2
    u = torch.rand(half, generator=g) * 2 * math.pi
    v = torch.rand(half, generator=g) * 2 * math.pi
    ring, tube = 0.6 * radius, 0.18 * radius
    torus = torch.stack(
        [
            (ring + tube * torch.cos(v)) * torch.cos(u),
            (ring + tube * torch.cos(v)) * torch.sin(u),
            tube * torch.sin(v),
        ],
        dim=1,
    )
    direction = torch.randn(n - half, 3, generator=g)
    sphere = 0.35 * radius * direction / direction.norm(dim=1, keepdim=True)
    means = torch.cat([torus, sphere]) + 0.005 * torch.randn(n, 3, generator=g)
    log_scales = math.log(0.012 * radius) + 0.3 * torch.randn(n, 3, generator=g)
    quats = torch.randn(n, 4, generator=g)
    quats = quats / quats.norm(dim=1, keepdim=True)
    opacity_logits = 2.0 + 0.5 * torch.randn(n, generator=g)
    colour = 0.5 + 0.5 * torch.tanh(2 * means / radius)  # position-coded colour in [0, 1]
    sh = torch.zeros(n, 16, 3)
    sh[:, 0, :] = (colour - 0.5) / 0.28209479177387814
    sh[:, 1:, :] = 0.02 * torch.randn(n, 15, 3, generator=g)
    export_ply(path, means, log_scales, quats, opacity_logits, sh)
    return path
