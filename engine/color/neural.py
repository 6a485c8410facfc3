"""DNGaussian's neural colour field: hash grid (position) + SH (direction) + two bias-free MLPs.

colour(mu, d) = act(MLP_c([SH4(d), geo(mu)])), geo(mu) = MLP_s(hash(mu))[1:], with
MLP_s: 32 → 64 → 64 → 65 and MLP_c: 80 → 64 → 3, ReLU between layers, no biases, and
act(h) = sigmoid(h) * 1.002 - 0.001. The density output (channel 0 of MLP_s) is never used by
the method, so it is not computed here (the 65th output row is kept only so the layer shapes
match the reference; see dngaussian-method.md §6).
"""

from __future__ import annotations

import torch
from torch import Tensor, nn

from sparsesplat.engine.color.hashgrid import HashGrid
from sparsesplat.engine.color.sh import sh_basis


class NeuralColorField(nn.Module):
    """Colour as a function of Gaussian centre and view direction."""

    def __init__(
        self,
        center: Tensor,
        bound: float,
        hidden: int = 64,
        geo_dim: int = 64,
        grid: HashGrid | None = None,
        generator: torch.Generator | None = None,
    ) -> None:
        """``center`` (3,) and ``bound`` (half-width) define the cube mapped onto the grid."""
        super().__init__()
        self.register_buffer("center", center.detach().float().clone())
        self.register_buffer("bound", torch.tensor(float(bound)))
        self.grid = grid if grid is not None else HashGrid(generator=generator)
        self.sigma_mlp = nn.Sequential(
            nn.Linear(self.grid.output_dim, hidden, bias=False),
            nn.ReLU(),
            nn.Linear(hidden, hidden, bias=False),
            nn.ReLU(),
            nn.Linear(hidden, 1 + geo_dim, bias=False),
        )
        self.color_mlp = nn.Sequential(
            nn.Linear(16 + geo_dim, hidden, bias=False),
            nn.ReLU(),
            nn.Linear(hidden, 3, bias=False),
        )
        if generator is not None:
            # Seeded init so two trainers with the same seed start identically.
            for layer in [*self.sigma_mlp, *self.color_mlp]:
                if isinstance(layer, nn.Linear):
                    bound_w = 1.0 / layer.in_features**0.5
                    with torch.no_grad():
                        layer.weight.copy_(
                            torch.rand(layer.weight.shape, generator=generator) * 2 * bound_w
                            - bound_w
                        )

    def geo_features(self, means: Tensor) -> Tensor:
        """(N, 3) world centres → (N, geo_dim) geometry features (density channel dropped)."""
        x = (means - self.center) / (2 * self.bound) + 0.5
        return self.sigma_mlp(self.grid(x))[:, 1:]

    def colors_from_features(self, geo: Tensor, dirs: Tensor) -> Tensor:
        """Per-view head: (N, geo_dim) features and (N, 3) unit directions → (N, 3) RGB."""
        h = self.color_mlp(torch.cat([sh_basis(dirs, 3), geo], dim=-1))
        return torch.sigmoid(h) * (1 + 2 * 0.001) - 0.001

    def forward(self, means: Tensor, camera_center: Tensor) -> Tensor:
        """Full evaluation for one view (training path; gradients reach means and weights)."""
        dirs = nn.functional.normalize(means - camera_center, dim=-1)
        return self.colors_from_features(self.geo_features(means), dirs)
