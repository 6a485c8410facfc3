"""The soft-depth term fused into the photometric render (``rasterize(opacity_depth=True)``).

The CPU kernel takes the gradient of a loss on ``opacity_depth`` in the same backward as the
photometric loss and adds it to the opacities alone. What it must equal: the photometric
render's gradients plus those of a second render whose centres, scales, rotations and features
are detached (the reference code's separate soft-depth pass), checked against the dense float64
reference under the float32 rule of ``tests/engine/numerics.py``.
"""

from __future__ import annotations

import pytest
import torch
from torch import Tensor

from sparsesplat.engine.raster import rasterize
from sparsesplat.engine.raster.reference import rasterize_reference
from sparsesplat.engine.raster.types import RasterInputs
from tests.engine.numerics import assert_float32_close

from .helpers import (
    PARAM_NAMES,
    camera,
    decision_windows,
    gradient_terms,
    loss_weights,
    random_gaussians,
)


def _fused_grads(
    tensors: list[Tensor], cam: object, seed: int, keep: Tensor, backend: str, dtype: torch.dtype
) -> list[Tensor]:
    """Gradients of w1.image + w2.depth + w3.alpha + w4.opacity_depth for every input."""
    leaves = [t.detach().to(dtype).clone().requires_grad_(True) for t in tensors]
    m, s, q, o, f = leaves
    bg = torch.zeros(f.shape[1], dtype=dtype)
    if backend == "reference32":
        out = rasterize_reference(
            RasterInputs(m, s, q, o, f, cam, bg, 0.01, 1e10, 0.3), dtype=torch.float32
        )
        empty = f.new_zeros(f.shape[0], 0)
        soft = rasterize_reference(
            RasterInputs(m.detach(), s.detach(), q.detach(), o, empty, cam, bg[:0], 0.01, 1e10,
                         0.3),
            dtype=torch.float32,
        ).depth  # fmt: skip
    else:
        out = rasterize(m, s, q, o, f, cam, bg, backend=backend, opacity_depth=True)
        assert out.opacity_depth is not None
        soft = out.opacity_depth
    w1, w2, w3 = loss_weights(out, seed)
    (w4,) = (w for w in loss_weights(out, seed + 1000)[1:2])
    mask = keep.to(dtype)
    loss = sum(
        ((v * w.to(dtype) * mask).sum()
         for v, w in zip((out.image, out.depth, out.alpha, soft), (w1, w2, w3, w4), strict=True)),
        torch.zeros((), dtype=dtype),
    )  # fmt: skip
    return list(torch.autograd.grad(loss, leaves, allow_unused=True))


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_fused_soft_depth_matches_two_renders_in_float64(seed: int) -> None:
    """Every input's gradient from one fused CPU render equals the float64 reference's
    photometric-plus-detached-soft-pass gradient within the float32 rule; the soft term reaches
    the opacities only (every other gradient equals the photometric render's alone)."""
    gs = random_gaussians(150, seed, channels=3)
    cam = camera(41, 33)
    windows = decision_windows(gs, cam)
    keep = ~windows.pixels
    tensors = gs.tensors()
    got = _fused_grads(tensors, cam, seed, keep, "cpu", torch.float32)
    ref64 = _fused_grads(tensors, cam, seed, keep, "reference", torch.float64)
    ref32 = _fused_grads(tensors, cam, seed, keep, "reference32", torch.float32)
    # Term sizes: the photometric loss's, plus (opacities only) those of a loss whose depth
    # weights are the soft term's (its image and alpha terms make the bound larger, not smaller).
    sizes = gradient_terms(gs, cam, seed, None, windows, [g.clone() for g in ref64])
    soft_sizes = gradient_terms(gs, cam, seed + 1000, None, windows, [g.clone() for g in ref64])
    sizes[3] = sizes[3] + soft_sizes[3]
    for name, a, b, c, size in zip(PARAM_NAMES, got, ref64, ref32, sizes, strict=False):
        assert_float32_close(a, b, c, size, f"{name} (seed {seed})")
    # The check can fail: the soft term changes the opacity gradient by far more than its bound.
    plain = [t.detach().clone().requires_grad_(True) for t in tensors]
    out = rasterize(*plain, cam, torch.zeros(3))
    w1, w2, w3 = loss_weights(out, seed)
    mask = keep.float()
    loss = ((out.image * w1 + 0) * mask).sum() + (out.depth * w2 * mask).sum()
    loss = loss + (out.alpha * w3 * mask).sum()
    without = torch.autograd.grad(loss, plain)
    assert float((without[3] - got[3]).abs().max()) > 10 * float(sizes[3].max()) * 2**-24
    for name, a, b in zip(PARAM_NAMES, without, got, strict=True):
        if name != "opacity_logits":
            scale = float(b.abs().max()) + 1e-30
            assert float((a - b).abs().max()) <= 1e-5 * scale, name


def test_opacity_depth_is_none_without_gradients() -> None:
    """No graph, no opacity-only depth (nothing would read its gradient)."""
    gs = random_gaussians(20, 0, channels=3)
    with torch.no_grad():
        out = rasterize(*gs.tensors(), camera(16, 12), opacity_depth=True)
    assert out.opacity_depth is None
