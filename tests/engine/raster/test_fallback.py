"""The CPU path where the native kernels cannot be built: the torch implementations stand in.

``cpu_backend`` asks the build for the tile rasterizer and the projection with
``load_*_or_none`` (None where the build fails, after one warning). Here the loaders are patched
to fail, and the renders and gradients must still meet the float32 rule against the float64
reference (``helpers.assert_matches_reference``), including the opacity-only depth.
"""

from __future__ import annotations

import pytest
import torch

from sparsesplat.engine.raster import cpu_backend, rasterize

from .helpers import assert_matches_reference, camera, random_gaussians


@pytest.mark.parametrize("missing", ["rasterizer", "projection"])
def test_the_cpu_path_runs_without_native_kernels(
    missing: str, seed: int, monkeypatch: pytest.MonkeyPatch
) -> None:
    """Without the tile kernels: the dense torch reference in float32; without the projection
    kernel: the torch projection and the native tile kernels."""
    name = (
        "load_extension_or_none" if missing == "rasterizer" else "load_projection_extension_or_none"
    )
    monkeypatch.setattr(cpu_backend, name, lambda: None)
    gs = random_gaussians(80, seed)
    out, _ = assert_matches_reference(gs, camera(30, 22), seed, f"no native {missing}")
    assert (out.stats is None) == (missing == "rasterizer")


def test_the_reference_fallback_gives_the_opacity_only_depth(
    seed: int, monkeypatch: pytest.MonkeyPatch
) -> None:
    """rasterize(opacity_depth=True) on the fallback: the depth again, whose gradient reaches
    the opacities only."""
    monkeypatch.setattr(cpu_backend, "load_extension_or_none", lambda: None)
    params = [t.clone().requires_grad_(True) for t in random_gaussians(40, seed).tensors()]
    out = rasterize(*params, camera(20, 16), backend="cpu", opacity_depth=True)
    assert out.opacity_depth is not None and out.image.dtype == torch.float32
    torch.testing.assert_close(out.opacity_depth, out.depth)
    out.opacity_depth.sum().backward()
    means, _, _, logits, features = params
    assert means.grad is None or float(means.grad.abs().max()) == 0.0
    assert logits.grad is not None and float(logits.grad.abs().max()) > 0
    assert features.grad is None or float(features.grad.abs().max()) == 0.0
