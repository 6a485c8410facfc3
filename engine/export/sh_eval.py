"""Real spherical harmonics up to degree 3, evaluated exactly as 3DGS does.

Coefficients are laid out ``(N, (degree + 1)^2, 3)``: index k over basis functions in the order
l = 0; l = 1 (m = -1, 0, 1); l = 2 (m = -2..2); l = 3 (m = -3..3), last axis RGB. The colour of a
Gaussian seen along unit direction d (from the camera centre towards the Gaussian) is
``max(sum_k Y_k(d) c_k + 0.5, 0)``; the +0.5 offset makes all-zero coefficients mid-grey.
"""

from __future__ import annotations

import math

import torch
from torch import Tensor

# Normalisation constants of the real SH basis with the sign convention 3DGS uses (the l = 1
# terms carry a minus sign on y and x). They are the standard values sqrt((2l+1)/4pi * ...).
C0 = 0.28209479177387814
C1 = 0.4886025119029199
C2 = (
    1.0925484305920792,
    -1.0925484305920792,
    0.31539156525252005,
    -1.0925484305920792,
    0.5462742152960396,
)
C3 = (
    -0.5900435899266435,
    2.890611442640554,
    -0.4570457994644658,
    0.3731763325901154,
    -0.4570457994644658,
    1.445305721320277,
    -0.5900435899266435,
)

MAX_DEGREE = 3


def num_coeffs(degree: int) -> int:
    """Number of basis functions of a real SH expansion of ``degree`` (``(degree + 1)^2``)."""
    return (degree + 1) ** 2


def degree_from_coeffs(k: int) -> int:
    """Inverse of :func:`num_coeffs`; raises ``ValueError`` when ``k`` is not a square 1..16."""
    degree = math.isqrt(k) - 1
    if k < 1 or (degree + 1) ** 2 != k or degree > MAX_DEGREE:
        raise ValueError(f"{k} SH coefficients is not (degree+1)^2 for a degree in 0..3")
    return degree


def sh_basis(dirs: Tensor, degree: int) -> Tensor:
    """Evaluate the basis functions: ``dirs`` (..., 3) unit vectors -> (..., (degree+1)^2)."""
    if not 0 <= degree <= MAX_DEGREE:
        raise ValueError(f"SH degree must be in 0..3, got {degree}")
    x, y, z = dirs.unbind(-1)
    out = [torch.full_like(x, C0)]
    if degree >= 1:
        out += [-C1 * y, C1 * z, -C1 * x]
    if degree >= 2:
        xx, yy, zz = x * x, y * y, z * z
        out += [
            C2[0] * x * y,
            C2[1] * y * z,
            C2[2] * (2.0 * zz - xx - yy),
            C2[3] * x * z,
            C2[4] * (xx - yy),
        ]
    if degree >= 3:
        out += [
            C3[0] * y * (3.0 * xx - yy),
            C3[1] * x * y * z,
            C3[2] * y * (4.0 * zz - xx - yy),
            C3[3] * z * (2.0 * zz - 3.0 * xx - 3.0 * yy),
            C3[4] * x * (4.0 * zz - xx - yy),
            C3[5] * z * (xx - yy),
            C3[6] * x * (xx - 3.0 * yy),
        ]
    return torch.stack(out, dim=-1)


def eval_sh(sh: Tensor, dirs: Tensor) -> Tensor:
    """RGB of each Gaussian along its direction: ``sh`` (N, K, 3), ``dirs`` (N, 3) -> (N, 3).

    ``dirs`` need not be normalised (they are here); the result is clamped below at 0 like 3DGS
    and not clamped above (the rasterizer's blending handles values > 1 as 3DGS does).
    """
    degree = degree_from_coeffs(sh.shape[1])
    unit = torch.nn.functional.normalize(dirs, dim=-1)
    basis = sh_basis(unit, degree).to(sh.dtype)  # (N, K)
    return (torch.einsum("nk,nkc->nc", basis, sh) + 0.5).clamp_min(0.0)


def rgb_to_dc(rgb: Tensor) -> Tensor:
    """The DC coefficient that renders as ``rgb`` from every direction (inverse of the offset)."""
    return (rgb - 0.5) / C0


def dc_to_rgb(dc: Tensor) -> Tensor:
    """View-independent colour of a DC coefficient (before clamping)."""
    return dc * C0 + 0.5
