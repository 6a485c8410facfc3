"""DNGaussian's neural colour field: hash grid (position) + SH (direction) + two bias-free MLPs.

colour(mu, d) = act(MLP_c([SH4(d), geo(mu)])), geo(mu) = MLP_s(hash(mu))[1:], with
MLP_s: 32 → 64 → 64 → 65 and MLP_c: 80 → 64 → 3, ReLU between layers, no biases, and
act(h) = sigmoid(h) * 1.002 - 0.001. The density output (channel 0 of MLP_s) is never used by
the method, so it is not computed here (the 65th output row is kept only so the layer shapes
match the reference; see dngaussian-method.md §6).

Training path (:meth:`NeuralColorField.forward`): the geometry feature feeds only the colour
head's first layer, and nothing non-linear sits between them, so
``W_c1[:, 16:] @ (W_s3[1:] @ h) = (W_c1[:, 16:] @ W_s3[1:]) @ h``: we multiply the two 64x64
weights once per call instead of running one more (N, 64) x (64, 64) product forward and two
backward (about a quarter of the MLP work). Same function and same parameters (their gradients
flow through the product); only float rounding differs. On the CPU with the native grid, the
MLPs of that path run as one fused kernel (``native.NativeColorMLP``); elsewhere as torch
products (``mlp.ColorMLP``). The inference path with cached geometry features keeps the
layer-by-layer form.
"""

from __future__ import annotations

from typing import cast

import torch
from torch import Tensor, nn

from sparsesplat.engine.color.hashgrid import HashGrid
from sparsesplat.engine.color.mlp import ColorMLP
from sparsesplat.engine.color.sh import sh_basis

_OUT_SCALE = 1 + 2 * 0.001
_OUT_SHIFT = 0.001


def _weight(seq: nn.Sequential, i: int) -> Tensor:
    """Weight of the i-th layer of ``seq`` (a bias-free nn.Linear)."""
    return cast(nn.Linear, seq[i]).weight


class NeuralColorField(nn.Module):
    """Colour as a function of Gaussian centre and view direction."""

    center: Tensor
    """(3,) centre of the grid cube (buffer)."""
    bound: Tensor
    """Half-width of the grid cube (scalar buffer)."""

    def __init__(
        self,
        center: Tensor,
        bound: float,
        hidden: int = 64,
        geo_dim: int = 64,
        grid: HashGrid | None = None,
        generator: torch.Generator | None = None,
        view_degree: int = 3,
    ) -> None:
        """``center`` (3,) and ``bound`` (half-width) define the cube mapped onto the grid;
        ``view_degree`` (0..3) is the highest SH band of the view direction the colour head
        sees (3: the reference's; lower bands are zeroed)."""
        super().__init__()
        if not 0 <= view_degree <= 3:
            raise ValueError(f"view_degree must be 0..3, got {view_degree}")
        self.view_degree = view_degree
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

    def _encode(self, means: Tensor) -> Tensor:
        """Hash-grid code of the centres mapped into the grid cube."""
        return self.grid((means - self.center) / (2 * self.bound) + 0.5)

    def _sh(self, dirs: Tensor) -> Tensor:
        """16-value SH direction code; the fused native kernel when the grid runs natively."""
        if self.grid.uses_native(dirs):
            from sparsesplat.engine.color.native import sh16_native

            code = sh16_native(dirs)
        else:
            code = sh_basis(dirs, 3)
        if self.view_degree < 3:
            # Bands above view_degree are zeroed, not dropped: the head keeps its 16 inputs.
            keep = (self.view_degree + 1) ** 2
            code = torch.cat([code[:, :keep], code.new_zeros(len(code), 16 - keep)], dim=1)
        return code

    def _hidden(self, code: Tensor) -> Tensor:
        """The sigma MLP's two ReLU layers (the input of its output layer)."""
        s = self.sigma_mlp
        h = torch.relu(nn.functional.linear(code, _weight(s, 0)))
        return torch.relu(nn.functional.linear(h, _weight(s, 2)))

    def geo_features(self, means: Tensor) -> Tensor:
        """(N, 3) world centres → (N, geo_dim) geometry features (density channel dropped)."""
        # Only rows 1.. of the output layer: the density row is never used.
        return nn.functional.linear(
            self._hidden(self._encode(means)), _weight(self.sigma_mlp, 4)[1:]
        )

    def _head(self, pre: Tensor) -> Tensor:
        """ReLU, the colour MLP's output layer and the scaled sigmoid."""
        h = nn.functional.linear(torch.relu(pre), _weight(self.color_mlp, 2))
        return torch.sigmoid(h) * _OUT_SCALE - _OUT_SHIFT

    def colors_from_features(self, geo: Tensor, dirs: Tensor) -> Tensor:
        """Per-view head: (N, geo_dim) features and (N, 3) unit directions → (N, 3) RGB."""
        w = _weight(self.color_mlp, 0)
        pre = nn.functional.linear(self._sh(dirs), w[:, :16])
        return self._head(torch.addmm(pre, geo, w[:, 16:].t()))

    def project_features(self, geo: Tensor) -> Tensor:
        """(N, geo_dim) features → (N, hidden): their share of the colour head's first layer.

        It does not depend on the view, so a renderer computes it once per model and each view
        pays only the 16-wide direction product (:meth:`colors_from_projected`)."""
        return nn.functional.linear(geo, _weight(self.color_mlp, 0)[:, 16:])

    def colors_from_projected(self, projected: Tensor, dirs: Tensor) -> Tensor:
        """Per-view head from :meth:`project_features`' output and (N, 3) unit directions."""
        w = _weight(self.color_mlp, 0)
        return self._head(torch.addmm(projected, self._sh(dirs), w[:, :16].t()))

    def forward(self, means: Tensor, camera_center: Tensor) -> Tensor:
        """Full evaluation for one view (training path; gradients reach means and weights)."""
        dirs = nn.functional.normalize(means - camera_center, dim=-1)
        w = _weight(self.color_mlp, 0)
        merged = w[:, 16:] @ _weight(self.sigma_mlp, 4)[1:]  # see the module docstring
        s = self.sigma_mlp
        mlp = ColorMLP.apply
        # The fused kernels are written for the field's shapes: hidden width 64, code 16/32/64.
        fits = w.shape[0] == _weight(s, 0).shape[0] == 64 and self.grid.output_dim in (16, 32, 64)
        if fits and self.grid.uses_native(means):
            from sparsesplat.engine.color.native import NativeColorMLP

            mlp = NativeColorMLP.apply
        return mlp(
            self._encode(means), self._sh(dirs), _weight(s, 0), _weight(s, 2), merged,
            w[:, :16], _weight(self.color_mlp, 2), _OUT_SCALE, _OUT_SHIFT,
        )  # fmt: skip
