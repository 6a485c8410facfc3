"""The rasterize contract: validation, dispatch, cheap passes, gradient plumbing."""

from __future__ import annotations

import pytest
import torch

from sparsesplat.engine.errors import RasterError
from sparsesplat.engine.raster import rasterize
from sparsesplat.engine.raster.reference import rasterize_reference
from sparsesplat.engine.raster.types import RasterInputs
from tests.engine.numerics import assert_float32_close

from .helpers import camera, decision_windows, random_gaussians


def test_bad_shapes_dtypes_and_arguments_raise_named_errors() -> None:
    """Each malformed argument raises RasterError naming that argument."""
    gs = random_gaussians(5, 0)
    args = gs.tensors()
    cam = camera()
    cases = {
        "means": [args[0][:, :2], *args[1:]],
        "log_scales": [args[0], args[1][:4], *args[2:]],
        "quats": [args[0], args[1], args[2][:, :3], *args[3:]],
        "opacity_logits": [*args[:3], args[3].double(), args[4]],
        "features": [*args[:4], args[4].unsqueeze(0)],
    }
    for name, bad in cases.items():
        with pytest.raises(RasterError, match=name):
            rasterize(*bad, cam)
    with pytest.raises(RasterError, match="background"):
        rasterize(*args, cam, background=torch.zeros(2))
    with pytest.raises(RasterError, match="backend"):
        rasterize(*args, cam, backend="metal")
    with pytest.raises(RasterError, match="near"):
        rasterize(*args, cam, near=2.0, far=1.0)
    with pytest.raises(RasterError, match="float64"):
        rasterize(*[a.double() for a in args], cam, backend="cpu")
    with pytest.raises(RasterError, match="cuda"):
        rasterize(*args, cam, backend="cuda")


def test_depth_only_pass_and_detached_inputs(seed: int) -> None:
    """C == 0 renders depth/alpha only; inputs that do not require grad get none. The depth and
    alpha of both passes agree with the float64 reference under the float32 rule."""
    gs = random_gaussians(50, seed)
    means = gs.means.clone().requires_grad_(True)
    logits = gs.opacity_logits.clone().requires_grad_(True)
    out = rasterize(means, gs.log_scales, gs.quats, logits, gs.features[:, :0], camera())
    assert out.image.shape == (0, 30, 40) and out.depth.shape == (1, 30, 40)
    (out.depth.sum() + out.alpha.sum()).backward()
    assert means.grad is not None and float(means.grad.abs().sum()) > 0, f"seed {seed}"
    assert logits.grad is not None and float(logits.grad.abs().sum()) > 0, f"seed {seed}"
    assert out.means2d.grad is not None and out.means2d.grad.shape == (50, 2)
    full = rasterize(*gs.tensors(), camera())
    keep = ~decision_windows(gs, camera()).pixels.unsqueeze(0)
    with torch.no_grad():
        exact = [t.double() for t in gs.tensors()]
        bg64 = torch.zeros(3, dtype=torch.float64)
        ref = rasterize_reference(RasterInputs(*exact, camera(), bg64, 0.01, 1e10, 0.3))
        args32 = RasterInputs(*gs.tensors(), camera(), torch.zeros(3), 0.01, 1e10, 0.3)
        ref32 = rasterize_reference(args32, dtype=torch.float32)
    for name in ("depth", "alpha"):
        b, c = getattr(ref, name)[keep], getattr(ref32, name)[keep]
        scale = float(b.abs().max())
        for what, render in (("C=3", full), ("C=0", out)):
            a = getattr(render, name).detach()[keep]
            assert_float32_close(a, b, c, scale, f"{name}, {what} (seed {seed})")


def test_no_grad_forward_keeps_no_graph() -> None:
    """Under no_grad nothing is recorded for backward and the result equals the grad path."""
    gs = random_gaussians(40, 3)
    params = [t.clone().requires_grad_(True) for t in gs.tensors()]
    with torch.no_grad():
        plain = rasterize(*params, camera())
    assert plain.image.grad_fn is None and plain.means2d.grad_fn is None
    graded = rasterize(*params, camera())
    assert graded.image.grad_fn is not None
    assert torch.equal(plain.image, graded.image.detach())
    assert plain.stats is not None and plain.stats["pairs_blended"] > 0
    assert plain.radii.dtype == torch.int32 and plain.radii.shape == (40,)
