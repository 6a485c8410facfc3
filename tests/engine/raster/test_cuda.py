"""gsplat (CUDA) backend against the native CPU kernel; skipped without a CUDA GPU."""

from __future__ import annotations

import random

import pytest
import torch

from sparsesplat.engine.raster import rasterize

from .helpers import camera, random_gaussians, rel_err

pytestmark = pytest.mark.cuda


@pytest.mark.parametrize("channels", [3, 0])
def test_gsplat_matches_cpu_kernel(channels: int) -> None:
    """Values and gradients agree to float32 tolerance (same gsplat semantics on both)."""
    pytest.importorskip("gsplat")
    seed = random.randrange(2**31)
    gs = random_gaussians(400, seed, channels=channels)
    cam = camera(96, 64, fx=80.0, fy=75.0, cx=45.0, cy=33.0)
    results = {}
    for dev in ("cpu", "cuda"):
        ps = [t.to(dev).requires_grad_(True) for t in gs.tensors()]
        c = cam.to(dev)
        out = rasterize(*ps, c)
        g = torch.Generator().manual_seed(seed)
        wi = torch.rand(out.image.shape, generator=g).to(dev)
        wd = torch.rand(out.depth.shape, generator=g).to(dev)
        ((out.image * wi).sum() + (out.depth * wd).sum() + out.alpha.sum()).backward()
        results[dev] = (out, [p.grad for p in ps])
    (a, ga), (b, gb) = results["cpu"], results["cuda"]
    for name in ("image", "depth", "alpha"):
        diff = (getattr(a, name).detach() - getattr(b, name).detach().cpu()).abs().max()
        assert float(diff) < 1e-4, f"{name} differs by {float(diff)} (seed {seed})"
    assert torch.equal(a.radii, b.radii.cpu()), f"radii differ (seed {seed})"
    for x, y in zip(ga, gb, strict=True):
        assert rel_err(y.cpu() if y is not None else None, x) < 1e-3, f"seed {seed}"
