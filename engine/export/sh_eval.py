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

from sparsesplat.engine.color.sh import C0, C1, C2, C3, sh_basis

__all__ = [
    "C0",
    "C1",
    "C2",
    "C3",
    "MAX_DEGREE",
    "dc_to_rgb",
    "degree_from_coeffs",
    "eval_sh",
    "num_coeffs",
    "rgb_to_dc",
    "sh_basis",
]

# The basis and its constants have one definition, shared with the colour models.
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
