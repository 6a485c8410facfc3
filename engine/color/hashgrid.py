"""Multiresolution hash grid encoding (Instant-NGP / torch-ngp ``gridencoder``) in plain torch.

Matches torch-ngp's layout with ``align_corners=False``: level l has ``scale = b^l * base - 1``
cells and ``ceil(scale) + 1`` vertices per axis, inputs in [0, 1] map to ``x * scale + 0.5``,
trilinear interpolation of the 8 surrounding vertices. A level whose dense vertex count fits the
table is indexed densely, otherwise by the XOR-of-primes spatial hash. Inputs outside [0, 1]
get zero features (as the CUDA kernel does). The table gradient is dense, so a standard dense
Adam sees exactly what the reference's does.

Two implementations with the same numbers: the native C++/OpenMP kernels (engine/color/cpu/, the
default for float32 CPU tensors) and the plain-torch one below (the reference, used for other
devices and dtypes, e.g. float64 gradcheck). ``backend="torch"`` or the environment variable
``SPARSESPLAT_HASHGRID=torch`` forces the torch one.
"""

from __future__ import annotations

import math
import os
from typing import Any

import torch
from torch import Tensor, nn

_PRIMES = (1, 2654435761, 805459861)
_CORNERS = torch.tensor([[(c >> d) & 1 for d in range(3)] for c in range(8)], dtype=torch.long)
BACKENDS = ("auto", "native", "torch")
"""Accepted ``HashGrid(backend=...)`` values (and of $SPARSESPLAT_HASHGRID)."""
BACKEND_ENV = "SPARSESPLAT_HASHGRID"
"""Environment variable overriding an 'auto' backend: 'torch' or 'native'."""
_NATIVE_FEATURES = (1, 2, 4, 8)


def vertex_weights(frac: Tensor, corners: Tensor) -> Tensor:
    """Trilinear weights (N, L, 8) of the 8 vertices around each point, from its (N, L, 3)
    position inside its cell: the product over the axes of ``frac`` (corner bit 1) or
    ``1 - frac`` (bit 0). Any float dtype (the float64 test references use it too)."""
    f = frac[:, :, None, :]
    w = torch.where(corners.bool(), f, 1.0 - f)
    # Three explicit products, not ``.prod(-1)``: on CUDA the backward of a product over a
    # 3-wide last axis runs torch's scan (cumprod) kernel, 35 ms per call at 50k points on an
    # H100, 90 % of a training iteration's GPU time (profiled 2026-11-26).
    return w[..., 0] * w[..., 1] * w[..., 2]


def vertex_rows(vertices: Tensor, levels: dict[str, Tensor]) -> Tensor:
    """Table rows (N, L, 8) of the (N, L, 8, 3) integer vertex coordinates: ``x + y s + z s^2``
    on a densely indexed level (s its vertices per axis), else the XOR-of-primes hash; modulo
    the level's size, plus its offset. ``levels``: :meth:`HashGrid._level_tables`."""
    stride = levels["stride"][None, :, None]
    x, y, z = vertices.unbind(-1)
    dense_idx = x + y * stride + z * stride * stride
    hashed = ((x * _PRIMES[0]) ^ (y * _PRIMES[1]) ^ (z * _PRIMES[2])) & 0xFFFFFFFF
    index = torch.where(levels["dense"][None, :, None], dense_idx, hashed)
    return index % levels["size"][None, :, None] + levels["offset"][None, :, None]


class _Gather(torch.autograd.Function):
    """rows = table[index] with a backward that is one ``index_add_`` into a dense gradient
    (autograd's advanced-indexing backward is several times slower on CPU)."""

    @staticmethod
    def forward(ctx: Any, table: Tensor, index: Tensor) -> Tensor:
        ctx.save_for_backward(index)
        ctx.rows = table.shape[0]
        return table.index_select(0, index)

    @staticmethod
    def backward(ctx: Any, grad: Tensor) -> tuple[Tensor, None]:
        (index,) = ctx.saved_tensors
        out = grad.new_zeros(ctx.rows, grad.shape[1])
        out.index_add_(0, index, grad)
        return out, None


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
        backend: str = "auto",
    ) -> None:
        """Build the levels and initialize the table U(-init_range, init_range).

        ``backend``: 'auto' (native kernels for float32 CPU inputs, torch otherwise; the
        environment variable SPARSESPLAT_HASHGRID=torch|native overrides it), 'native' (error
        when the inputs do not suit it) or 'torch'."""
        super().__init__()
        if backend not in BACKENDS:
            raise ValueError(f"HashGrid backend: expected one of {BACKENDS}, got {backend!r}")
        self.backend = backend
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

    def _level_tables(self, device: torch.device) -> dict[str, Tensor]:
        """Per-level constants as tensors (scale, size, offset, dense flag, dense stride) and
        the 8 corner offsets, made once per device (not copied to the GPU on every call)."""
        cache = getattr(self, "_consts", None)
        if cache is None or cache["scale"].device != device:
            cache = {
                "scale": torch.tensor(self.scales, dtype=torch.float32, device=device),
                "size": torch.tensor(self.sizes, dtype=torch.long, device=device),
                "offset": torch.tensor(self.offsets[:-1], dtype=torch.long, device=device),
                "dense": torch.tensor(self.dense, dtype=torch.bool, device=device),
                "stride": torch.tensor(
                    [r + 1 for r in self.resolutions], dtype=torch.long, device=device
                ),
                "corners": _CORNERS.to(device),
            }
            self._consts = cache
        return cache

    def layout(self) -> tuple[list[float], list[int], list[int], list[int], list[bool]]:
        """Per-level (scales, sizes, dense strides, offsets incl. the total rows, dense flags)."""
        strides = [r + 1 for r in self.resolutions]
        return self.scales, self.sizes, strides, self.offsets, self.dense

    def uses_native(self, x: Tensor) -> bool:
        """Whether :meth:`forward` would run the native kernels for input ``x``."""
        backend = self.backend
        if backend == "auto":
            backend = os.environ.get(BACKEND_ENV, "auto").strip().lower() or "auto"
            if backend not in BACKENDS:
                raise ValueError(f"${BACKEND_ENV}: expected one of {BACKENDS}, got {backend!r}")
        if backend == "torch":
            return False
        suited = (
            x.device.type == "cpu"
            and self.embeddings.device.type == "cpu"
            and x.dtype == torch.float32
            and self.embeddings.dtype == torch.float32
            and self.n_features in _NATIVE_FEATURES
        )
        if backend == "native" and not suited:
            raise ValueError(
                f"HashGrid backend='native' needs float32 CPU inputs and table and "
                f"n_features in {_NATIVE_FEATURES}; got x {x.dtype} on {x.device}, table "
                f"{self.embeddings.dtype} on {self.embeddings.device}, n_features={self.n_features}"
            )
        if suited and backend == "auto":
            # Where the kernels cannot be built: the torch implementation (one warning).
            from sparsesplat.engine.color.build import load_extension_or_none

            return load_extension_or_none() is not None
        return suited

    def forward(self, x: Tensor) -> Tensor:
        """Encode (N, 3) points in [0, 1]; points outside get zeros (and no gradient)."""
        if x.dim() != 2 or x.shape[-1] != 3:
            raise ValueError(f"HashGrid input: expected shape (N, 3), got {tuple(x.shape)}")
        if self.uses_native(x):
            from sparsesplat.engine.color.native import encode_native

            return encode_native(x, self.embeddings, self.layout())
        return self.forward_torch(x)

    def forward_torch(self, x: Tensor) -> Tensor:
        """The plain-torch reference implementation of :meth:`forward`.

        All levels are gathered in one indexing op so the backward builds ONE dense gradient
        of the table (per-level gathers would each allocate a table-sized zero tensor)."""
        inside = ((x >= 0) & (x <= 1)).all(dim=-1, keepdim=True)
        x = torch.where(inside, x, torch.zeros_like(x))
        c = self._level_tables(x.device)
        corners = c["corners"]  # (8, 3)
        pos = x[:, None, :] * c["scale"][None, :, None] + 0.5  # (N, L, 3)
        base = torch.floor(pos)
        frac = pos - base
        w = vertex_weights(frac, corners)  # (N, L, 8)
        index = vertex_rows(base.long()[:, :, None, :] + corners, c)  # (N, L, 8)
        rows = _Gather.apply(self.embeddings, index.reshape(-1)).reshape(*index.shape, -1)
        out = (w.unsqueeze(-1) * rows).sum(dim=2).reshape(x.shape[0], -1)
        return out * inside.to(out.dtype)
