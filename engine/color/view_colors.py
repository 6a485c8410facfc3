"""Per-view colours of a fixed (trained) model, with everything view-independent done once.

A renderer builds one of these per loaded model; each view then pays only what depends on the
camera centre:

- :class:`NeuralViewColors` (exact): the neural field's hash grid, sigma MLP and the geometry
  features' share of the colour head's first layer are computed at construction; a view costs
  the 16-value direction code, one (N, 16) x (16, hidden) product, the (N, hidden) x (hidden, 3)
  output layer and the sigmoid. Same function as the trainer's evaluation render; only float
  rounding differs (the two matrix products are summed in another order).
- :class:`BakedViewColors`: degree-3 SH coefficients (the field baked by least squares, see
  ``engine/export/bake.py``) evaluated along each view direction, the 3DGS colour rule. About
  a sixth of the neural head's arithmetic, at the bake's fidelity.
"""

from __future__ import annotations

import math

import torch
from torch import Tensor, nn

from sparsesplat.engine.color.neural import NeuralColorField
from sparsesplat.engine.color.sh import eval_sh


def view_directions(means: Tensor, camera_center: Tensor) -> Tensor:
    """(N, 3) unit directions from the camera centre to each Gaussian (the 3DGS convention)."""
    return nn.functional.normalize(means - camera_center, dim=-1)


class NeuralViewColors:
    """The neural colour field of a fixed set of Gaussians, evaluated per view."""

    def __init__(self, field: NeuralColorField, means: Tensor) -> None:
        """Precompute the view-independent part of ``field`` at the centres ``means`` (N, 3)."""
        with torch.no_grad():
            self.field = field
            self.means = means.detach()
            self.projected = field.project_features(field.geo_features(self.means)).contiguous()

    def __call__(self, camera_center: Tensor) -> Tensor:
        """(N, 3) RGB seen from ``camera_center`` (3,)."""
        with torch.no_grad():
            dirs = view_directions(self.means, camera_center)
            return self.field.colors_from_projected(self.projected, dirs)


class BakedViewColors:
    """SH coefficients (N, K, 3) evaluated per view: ``max(sum_k Y_k(d) c_k + 0.5, 0)``."""

    def __init__(self, sh: Tensor, means: Tensor) -> None:
        """``sh`` (N, K, 3) with K a square 1..16, for the Gaussians centred at ``means``."""
        k = sh.shape[1] if sh.dim() == 3 else 0
        degree = math.isqrt(k) - 1
        fits = sh.dim() == 3 and sh.shape[0] == means.shape[0] and sh.shape[2] == 3
        if not fits or (degree + 1) ** 2 != k or not 0 <= degree <= 3:
            raise ValueError(
                f"SH coefficients of shape {tuple(sh.shape)} do not fit {means.shape[0]} Gaussians"
                " (expected (N, (degree + 1)^2, 3), degree 0..3)"
            )
        self.degree = degree
        self.sh = sh.detach().to(means.device, means.dtype).contiguous()
        self.means = means.detach()

    def __call__(self, camera_center: Tensor) -> Tensor:
        """(N, 3) RGB seen from ``camera_center`` (3,)."""
        with torch.no_grad():
            return eval_sh(self.sh, view_directions(self.means, camera_center), self.degree)
