"""Scene builders and comparisons shared by the rasterizer tests."""

from __future__ import annotations

from dataclasses import dataclass

import torch
from torch import Tensor

from sparsesplat.engine.camera import Camera
from sparsesplat.engine.raster import RasterOutput, rasterize

PARAM_NAMES = ("means", "log_scales", "quats", "opacity_logits", "features")


@dataclass
class Gaussians:
    """Raw rasterizer inputs (float32, CPU)."""

    means: Tensor
    log_scales: Tensor
    quats: Tensor
    opacity_logits: Tensor
    features: Tensor

    def tensors(self) -> list[Tensor]:
        """The five tensors in ``rasterize`` order."""
        return [self.means, self.log_scales, self.quats, self.opacity_logits, self.features]


def random_gaussians(n: int, seed: int, channels: int = 3, spread: float = 0.8) -> Gaussians:
    """N Gaussians a few units in front of an identity camera, a few pixels wide at 50 px focal."""
    g = torch.Generator().manual_seed(seed)
    means = torch.randn(n, 3, generator=g) * spread + torch.tensor([0.0, 0.0, 4.0])
    log_scales = torch.randn(n, 3, generator=g) * 0.4 - 2.3
    quats = torch.randn(n, 4, generator=g)
    logits = torch.randn(n, generator=g) * 1.5
    feats = torch.rand(n, channels, generator=g)
    return Gaussians(means, log_scales, quats, logits, feats)


def camera(width: int = 40, height: int = 30, fx: float = 40.0, fy: float | None = None,
           cx: float | None = None, cy: float | None = None,
           pose: Tensor | None = None) -> Camera:  # fmt: skip
    """A pinhole camera; identity pose unless given."""
    return Camera(
        torch.eye(4) if pose is None else pose,
        fx,
        fx if fy is None else fy,
        width / 2 if cx is None else cx,
        height / 2 if cy is None else cy,
        width,
        height,
    )


def render_with_grads(
    gs: Gaussians, cam: Camera, backend: str, seed: int, background: Tensor | None = None,
    **kwargs: object,
) -> tuple[RasterOutput, list[Tensor | None]]:  # fmt: skip
    """Render, back-propagate a seeded random linear loss of image, depth and alpha."""
    params = [t.detach().clone().requires_grad_(True) for t in gs.tensors()]
    out = rasterize(*params, cam, background=background, backend=backend, **kwargs)  # type: ignore[arg-type]
    g = torch.Generator().manual_seed(seed + 7)
    loss = (out.image * torch.rand(out.image.shape, generator=g)).sum()
    loss = loss + (out.depth * torch.rand(out.depth.shape, generator=g)).sum()
    loss = loss + (out.alpha * torch.rand(out.alpha.shape, generator=g)).sum()
    if loss.requires_grad:
        loss.backward()
    return out, [p.grad for p in params]


def rel_err(a: Tensor | None, b: Tensor | None) -> float:
    """Relative L2 error of ``a`` against ``b`` (missing gradients count as zeros)."""
    if a is None and b is None:
        return 0.0
    ref = torch.zeros_like(a if b is None else b).double() if b is None else b.double()
    got = torch.zeros_like(ref) if a is None else a.double()
    return float((got - ref).norm() / ref.norm().clamp_min(1e-12))


def assert_finite(out: RasterOutput, grads: list[Tensor | None], what: str) -> None:
    """Every output and gradient is finite."""
    for name, t in (("image", out.image), ("depth", out.depth), ("alpha", out.alpha)):
        assert torch.isfinite(t).all(), f"{what}: non-finite {name}"
    for name, g in zip(PARAM_NAMES, grads, strict=True):
        assert g is None or torch.isfinite(g).all(), f"{what}: non-finite grad of {name}"


def assert_matches_reference(
    gs: Gaussians, cam: Camera, seed: int, what: str, tol: float = 1e-4,
    background: Tensor | None = None, **kwargs: object,
) -> tuple[RasterOutput, list[Tensor | None]]:  # fmt: skip
    """CPU kernel output and gradients agree with the float64 reference; both finite."""
    out, grads = render_with_grads(gs, cam, "cpu", seed, background, **kwargs)
    ref, ref_grads = render_with_grads(gs, cam, "reference", seed, background, **kwargs)
    assert_finite(out, grads, f"{what} (cpu)")
    assert_finite(ref, ref_grads, f"{what} (reference)")
    for name in ("image", "depth", "alpha"):
        a, b = getattr(out, name).detach().double(), getattr(ref, name).detach().double()
        if a.numel() == 0:
            continue
        scale = float(b.abs().max().clamp_min(1.0))
        err = float((a - b).abs().max()) / scale
        assert err < tol, f"{what}: {name} differs from reference by {err:.3g} (seed {seed})"
    # Culling must agree exactly; the ceil'd extent may differ by a pixel for huge footprints.
    assert torch.equal(out.radii > 0, ref.radii > 0), f"{what}: culling differs (seed {seed})"
    slack = (ref.radii.double() * 1e-5).clamp_min(1.0)
    assert ((out.radii - ref.radii).abs() <= slack).all(), f"{what}: radii differ (seed {seed})"
    for name, a, b in zip(PARAM_NAMES, grads, ref_grads, strict=True):
        err = rel_err(a, b)
        assert err < tol, f"{what}: grad of {name} rel err {err:.3g} vs reference (seed {seed})"
    return out, grads
