"""Differentiable EWA projection of 3D Gaussians to the image plane, with gsplat 1.5 semantics.

Shared by the float64 reference and the native CPU backend so both agree on the 2D Gaussians. The
rules restated from gsplat's ``fully_fused_projection``: the Jacobian uses the view-space position
clamped to 1.3x the field of view, ``eps2d`` is added to the 2D covariance before inverting it,
Gaussians outside ``(near, far)`` or with a non-positive determinant are culled, and the screen
extent is opacity-aware: ``min(3.33, sqrt(2 ln(255 o)))`` standard deviations per axis.
"""

from __future__ import annotations

from dataclasses import dataclass

import torch
from torch import Tensor

from sparsesplat.engine.camera import Camera

ALPHA_THRESHOLD = 1.0 / 255.0
"""Pairs with alpha below this are skipped (gsplat's ALPHA_THRESHOLD)."""
MAX_EXTENT_SIGMA = 3.33
"""Largest screen extent, in standard deviations per axis (gsplat 1.5)."""


@dataclass
class Projected:
    """2D Gaussians produced by :func:`project`, one row per input Gaussian."""

    means2d: Tensor
    """(N, 2) projected centres in pixels (differentiable)."""
    conics: Tensor
    """(N, 3) upper triangle (a, b, c) of the inverse 2D covariance (differentiable)."""
    depths: Tensor
    """(N,) view-space z of the centres (differentiable)."""
    opacities: Tensor
    """(N,) sigmoid of the opacity logits (differentiable)."""
    radii: Tensor
    """(N, 2) int32 opacity-aware screen extent per axis in pixels; 0 where culled (no grad)."""


def quat_to_rotmat(quats: Tensor) -> Tensor:
    """(N, 4) wxyz quaternions (any norm) to (N, 3, 3) rotation matrices."""
    q = quats / quats.norm(dim=-1, keepdim=True).clamp_min(1e-12)
    w, x, y, z = q.unbind(-1)
    rows = [
        1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y),
        2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x),
        2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y),
    ]  # fmt: skip
    return torch.stack(rows, dim=-1).reshape(*q.shape[:-1], 3, 3)


def view_frame(camera: Camera, device: torch.device | str = "cpu") -> tuple[Tensor, Tensor]:
    """The view rotation R and the camera centre c = -R^T t, both float64 on ``device``: the
    frame in which ``R (m - c)`` is formed (shared with the native projection, so both start
    from bit-identical values)."""
    w2c = camera.world_to_camera.to(device=device, dtype=torch.float64)
    rot64 = w2c[:3, :3]
    return rot64, -rot64.T @ w2c[:3, 3]


def _camera_space_means(means: Tensor, camera: Camera) -> tuple[Tensor, Tensor]:
    """View-space means and the view rotation, both in ``means.dtype``.

    ``R m + t`` is computed as ``R (m - c)`` with ``m - c`` formed in float64: far from the origin
    (1e4 units) the float32 sum ``R m + t`` would cancel catastrophically near the camera.
    """
    rot64, centre64 = view_frame(camera, means.device)
    rel = (means.to(torch.float64) - centre64).to(means.dtype)
    rot = rot64.to(means.dtype)
    return rel @ rot.T, rot


def project(
    means: Tensor,
    log_scales: Tensor,
    quats: Tensor,
    opacity_logits: Tensor,
    camera: Camera,
    near: float,
    far: float,
    eps2d: float,
) -> Projected:
    """Project N 3D Gaussians through ``camera``; every output is finite, culled rows included."""
    mc, rot = _camera_space_means(means, camera)
    x, y, z = mc.unbind(-1)
    in_depth = (z > near) & (z < far)
    # Culled rows get a harmless stand-in depth so no inf/NaN enters the graph (NaN * 0 = NaN).
    zs = torch.where(in_depth, z, torch.ones_like(z))

    # Covariance factor in camera space, V = R_view R_q S, so cov_cam = V V^T. (R_q^T R_view^T) is
    # one (3N, 3) x (3, 3) GEMM; batched 3x3 matmuls are several times slower in torch.
    rq = quat_to_rotmat(quats)
    v = (rq.transpose(-1, -2).reshape(-1, 3) @ rot.T).reshape(-1, 3, 3).transpose(-1, -2)
    v = v * torch.exp(log_scales).unsqueeze(-2)  # scale the columns

    fx, fy, cx, cy = camera.fx, camera.fy, camera.cx, camera.cy
    w, h = camera.width, camera.height
    lim_xp = (w - cx) / fx + 0.3 * (0.5 * w / fx)
    lim_xn = cx / fx + 0.3 * (0.5 * w / fx)
    lim_yp = (h - cy) / fy + 0.3 * (0.5 * h / fy)
    lim_yn = cy / fy + 0.3 * (0.5 * h / fy)
    zero = torch.zeros_like(zs)
    inv_z = 1.0 / zs
    # Jacobian rows of the perspective map at the FoV-clamped position (gsplat's persp_proj):
    # J0 = (fx / z, 0, -fx tx / z^2), J1 = (0, fy / z, -fy ty / z^2), with tx / z clamped.
    ux = torch.clamp(x * inv_z, -lim_xn, lim_xp)
    uy = torch.clamp(y * inv_z, -lim_yn, lim_yp)
    t0 = (fx * inv_z).unsqueeze(-1) * (v[:, 0] - ux.unsqueeze(-1) * v[:, 2])  # J0 V
    t1 = (fy * inv_z).unsqueeze(-1) * (v[:, 1] - uy.unsqueeze(-1) * v[:, 2])  # J1 V
    a = (t0 * t0).sum(-1) + eps2d
    b = (t0 * t1).sum(-1)
    c = (t1 * t1).sum(-1) + eps2d
    # det(T T^T + eps I) via Lagrange's identity, |t0 x t1|^2 + eps (a0 + c0) + eps^2: the plain
    # a c - b^2 cancels catastrophically in float32 for needle-like (near-singular) footprints.
    cross = torch.linalg.cross(t0, t1, dim=-1)
    det = (cross * cross).sum(-1) + eps2d * (a + c - eps2d)
    valid = in_depth & (det > 0) & torch.isfinite(det)
    det_s = torch.where(valid, det, torch.ones_like(det))
    conics = torch.stack([c / det_s, -b / det_s, a / det_s], dim=-1)
    conics = torch.where(valid.unsqueeze(-1), conics, torch.zeros_like(conics))
    means2d = torch.stack([fx * x * inv_z + cx, fy * y * inv_z + cy], dim=-1)
    opacities = torch.sigmoid(opacity_logits)

    with torch.no_grad():
        op = opacities.to(torch.float64)
        valid = valid & (op >= ALPHA_THRESHOLD)
        extent = torch.sqrt(2.0 * torch.log(op.clamp_min(ALPHA_THRESHOLD) / ALPHA_THRESHOLD))
        extent = extent.clamp(max=MAX_EXTENT_SIGMA)
        a64, c64 = a.detach().to(torch.float64), c.detach().to(torch.float64)
        rx = torch.ceil(extent * torch.sqrt(a64.clamp_min(0)))
        ry = torch.ceil(extent * torch.sqrt(c64.clamp_min(0)))
        mx, my = means2d[:, 0].detach().double(), means2d[:, 1].detach().double()
        inside = (mx + rx > 0) & (mx - rx < w) & (my + ry > 0) & (my - ry < h)
        keep = valid & inside & (rx > 0) & (ry > 0)
        big = float(2**30)  # int32-safe cap for enormous Gaussians
        radii = torch.stack([rx.clamp(max=big), ry.clamp(max=big)], dim=-1)
        radii = torch.where(keep.unsqueeze(-1), radii, torch.zeros_like(radii)).to(torch.int32)
    return Projected(means2d, conics, torch.where(in_depth, z, zero), opacities, radii)
