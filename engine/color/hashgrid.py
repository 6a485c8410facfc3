"""Multiresolution hash grid encoding (Instant-NGP / torch-ngp ``gridencoder``) in plain torch.

Matches torch-ngp's layout with ``align_corners=False``: level l has ``scale = b^l * base - 1``
cells and ``ceil(scale) + 1`` vertices per axis, inputs in [0, 1] map to ``x * scale + 0.5``,
trilinear interpolation of the 8 surrounding vertices. A level whose dense vertex count fits the
table is indexed densely, otherwise by the XOR-of-primes spatial hash. Inputs outside [0, 1]
get zero features (as the CUDA kernel does). The backward pass is autograd's scatter-add into a
dense gradient of the table, so a standard dense Adam sees exactly what the reference's does.
"""

from __future__ import annotations

import math

import torch
from torch import Tensor, nn

_PRIMES = (1, 2654435761, 805459861)
_CORNERS = torch.tensor([[(c >> d) & 1 for d in range(3)] for c in range(8)], dtype=torch.long)


class HashGrid(nn.Module):
    """3D multiresolution hash encoding: (N, 3) in [0, 1] → (N, n_levels * n_features)."""

    def __init__(
        self,
        n_levels: int = 16,
        n_features: int = 2,
        log2_table_size: int = 19,
        base_resolution: int = 16,
        finest_resolution: int = 2048,
        init_range: float = 1e-4,
        generator: torch.Generator | None = None,
    ) -> None:
        """Build the levels and initialize the table U(-init_range, init_range)."""
        super().__init__()
        self.n_levels = n_levels
        self.n_features = n_features
        self.table_size = 2**log2_table_size
        self.output_dim = n_levels * n_features
        growth = (
            math.exp2(math.log2(finest_resolution / base_resolution) / (n_levels - 1))
            if n_levels > 1
            else 1.0
        )
        self.scales: list[float] = []
        self.resolutions: list[int] = []
        self.sizes: list[int] = []
        self.dense: list[bool] = []
        offsets = [0]
        for level in range(n_levels):
            scale = math.exp2(level * math.log2(growth)) * base_resolution - 1.0
            resolution = math.ceil(scale) + 1
            vertices = (resolution + 1) ** 3
            size = min(self.table_size, vertices)
            size = int(math.ceil(size / 8) * 8)
            self.scales.append(scale)
            self.resolutions.append(resolution)
            self.sizes.append(size)
            self.dense.append(vertices <= size)
            offsets.append(offsets[-1] + size)
        self.offsets = offsets
        table = torch.rand(offsets[-1], n_features, generator=generator)
        self.embeddings = nn.Parameter(table * 2 * init_range - init_range)

    def _indices(self, grid: Tensor, level: int) -> Tensor:
        """(..., 3) integer vertex coordinates → (...) rows of the level's table."""
        size = self.sizes[level]
        if self.dense[level]:
            stride = self.resolutions[level] + 1
            index = grid[..., 0] + grid[..., 1] * stride + grid[..., 2] * stride * stride
        else:
            index = grid[..., 0] * _PRIMES[0]
            index = index ^ (grid[..., 1] * _PRIMES[1])
            index = index ^ (grid[..., 2] * _PRIMES[2])
            index = index & 0xFFFFFFFF
        return index % size + self.offsets[level]

    def forward(self, x: Tensor) -> Tensor:
        """Encode (N, 3) points in [0, 1]; points outside get zeros (and no gradient)."""
        inside = ((x >= 0) & (x <= 1)).all(dim=-1, keepdim=True)
        x = torch.where(inside, x, torch.zeros_like(x))
        corners = _CORNERS.to(x.device)
        feats = []
        for level in range(self.n_levels):
            pos = x * self.scales[level] + 0.5
            base = torch.floor(pos)
            frac = pos - base
            grid = base.long().unsqueeze(1) + corners  # (N, 8, 3)
            # Trilinear weights: prod over axes of frac or (1 - frac).
            w = torch.where(corners.bool(), frac.unsqueeze(1), 1.0 - frac.unsqueeze(1)).prod(-1)
            rows = self.embeddings[self._indices(grid, level)]  # (N, 8, F)
            feats.append((w.unsqueeze(-1) * rows).sum(dim=1))
        out = torch.cat(feats, dim=-1)
        return out * inside.to(out.dtype)
