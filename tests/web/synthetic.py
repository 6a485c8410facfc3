"""A synthetic splat model for the frame-rate measurements (the viewer's drawing, the live
view's server renders)."""

from __future__ import annotations

import math
from pathlib import Path

import torch
from torch import Tensor

from sparsesplat.engine.export.ply import export_ply


def synthetic_gaussians(n: int = 50_000, seed: int = 0, radius: float = 0.8) -> dict[str, Tensor]:
    """``n`` small opaque Gaussians (SH degree 3) on a torus and a sphere of about ``radius``
    around the origin, the size of a Blender scene's object: what a trained object model looks
    like to a renderer (small splats, little overdraw), at a chosen count. Keys: the
    checkpoint's parameter names plus ``sh`` (N, 16, 3)."""
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
    return {"means": means, "log_scales": log_scales, "quats": quats,
            "opacity_logits": opacity_logits, "sh": sh}  # fmt: skip


def write_synthetic_ply(path: Path, n: int = 50_000, seed: int = 0, radius: float = 0.8) -> Path:
    """The :func:`synthetic_gaussians` as a .ply export."""
    g = synthetic_gaussians(n, seed, radius)
    export_ply(path, g["means"], g["log_scales"], g["quats"], g["opacity_logits"], g["sh"])
    return path


def replace_checkpoint_gaussians(path: Path, n: int = 50_000, seed: int = 0) -> Path:
    """Swap the Gaussians of the checkpoint at ``path`` for :func:`synthetic_gaussians` (its
    colour model stays: the neural field colours any positions), so that the render worker
    serves a model of ``n`` Gaussians; written atomically, as the trainer writes it."""
    from sparsesplat.engine.model.checkpoint import load_checkpoint, save_checkpoint

    state = load_checkpoint(path)
    g = synthetic_gaussians(n, seed)
    params = {k: g[k].float() for k in ("means", "log_scales", "quats", "opacity_logits")}
    if "sh_dc" in state["gaussians"]:  # an SH-colour model: its own coefficients
        params["sh_dc"] = g["sh"][:, :1].float()
        if "sh_rest" in state["gaussians"]:
            k = state["gaussians"]["sh_rest"].shape[1]
            params["sh_rest"] = g["sh"][:, 1 : 1 + k].float()
    state["gaussians"] = params
    return save_checkpoint(state, path)
