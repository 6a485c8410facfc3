"""Numerical stability: extreme inputs stay finite and agree with the float64 reference.

Agreement is the float32 rule of ``tests/engine/numerics.py`` (via ``assert_matches_reference``):
ill-conditioned scenes need no looser tolerance of their own, because the bound scales with
torch float32's own error on the same scene.
"""

from __future__ import annotations

import math

import pytest
import torch

from sparsesplat.engine.raster.reference import rasterize_reference
from sparsesplat.engine.raster.types import RasterInputs
from tests.engine.numerics import assert_float32_close

from .helpers import (
    Gaussians,
    assert_finite,
    assert_matches_reference,
    camera,
    decision_windows,
    random_gaussians,
    render_with_grads,
)


@pytest.mark.parametrize("scale", [1e-8, 1e4])
def test_extreme_scales(scale: float, seed: int) -> None:
    """Scales of 1e-8 (a point, eps2d keeps it one pixel wide) and 1e4 (covers everything)."""
    gs = random_gaussians(30, seed)
    gs.log_scales[:5] = math.log(scale)
    assert_matches_reference(gs, camera(), seed, f"scale {scale}")


def test_near_singular_covariance(seed: int) -> None:
    """Needle-thin Gaussians with a tiny eps2d: 2D covariances close to singular."""
    gs = random_gaussians(20, seed)
    gs.log_scales[:, 1:] = math.log(1e-7)
    gs.log_scales[:, 0] = math.log(0.3)
    assert_matches_reference(gs, camera(), seed, "near-singular, eps2d 0.3")
    # With almost no dilation the conics reach ~1e4: one roundoff of a projected centre moves a
    # needle's alpha by 1e-4, and float32 keeps ~3 digits of its gradients (torch's too). The
    # errors of 20 needles are too few draws for torch's to be a stable scale, so the check
    # pools 8 copies of the scene, each input moved by one float32 step. Up to a fifth of the
    # pixels (those along the needles) sit within float32's error of the 1/255 threshold.
    assert_matches_reference(gs, camera(), seed, "near-singular, eps2d 1e-4", draws=8,
                             max_ambiguous=0.2, eps2d=1e-4)  # fmt: skip


def test_on_optical_axis_and_at_near_plane(seed: int) -> None:
    """A Gaussian on the optical axis, one just past the near plane, one exactly on it."""
    gs = random_gaussians(6, seed)
    gs.means[0] = torch.tensor([0.0, 0.0, 3.0])
    gs.means[1] = torch.tensor([0.01, -0.01, 0.0105])
    gs.means[2] = torch.tensor([0.0, 0.0, 0.01])
    out, _ = assert_matches_reference(gs, camera(), seed, "optical axis / near plane")
    assert int(out.radii[0]) > 0 and int(out.radii[2]) == 0, f"seed {seed}"


def test_behind_camera_gets_no_gradient(seed: int) -> None:
    """Centres behind the camera are culled: radius 0, zero (finite) gradients."""
    gs = random_gaussians(10, seed)
    gs.means[:4, 2] = -torch.rand(4, generator=torch.Generator().manual_seed(seed)) * 5 - 0.1
    out, grads = assert_matches_reference(gs, camera(), seed, "behind camera")
    assert (out.radii[:4] == 0).all(), f"seed {seed}"
    assert grads[0] is not None and float(grads[0][:4].abs().sum()) == 0.0, f"seed {seed}"


def test_camera_inside_gaussian(seed: int) -> None:
    """A huge Gaussian whose ellipsoid contains the camera (centre barely in front)."""
    gs = random_gaussians(8, seed)
    gs.means[0] = torch.tensor([0.1, 0.0, 0.5])
    gs.log_scales[0] = torch.tensor([2.0, 2.0, 2.0])
    assert_matches_reference(gs, camera(), seed, "camera inside")


@pytest.mark.parametrize("logit", [30.0, -30.0])
def test_extreme_opacity_logits(logit: float, seed: int) -> None:
    """Opacity logits of +-30: clamped alpha (no gradient through the clamp) or fully culled."""
    gs = random_gaussians(25, seed)
    gs.opacity_logits[:10] = logit
    assert_matches_reference(gs, camera(), seed, f"logit {logit}")


def test_features_outside_unit_range(seed: int) -> None:
    """Features far outside [0, 1] blend linearly like any other value."""
    gs = random_gaussians(25, seed, channels=4)
    gs.features = gs.features * 20 - 7
    assert_matches_reference(gs, camera(), seed, "wide features", background=torch.tensor(
        [-2.0, 3.0, 0.5, 9.0]))  # fmt: skip


@pytest.mark.parametrize("n", [0, 1])
def test_zero_and_one_gaussian(n: int, seed: int) -> None:
    """Empty scenes render the background; a single Gaussian matches the reference."""
    gs = random_gaussians(n, seed)
    if n == 1:
        gs.means[0] = torch.tensor([0.05, -0.02, 2.0])
    bg = torch.tensor([0.2, 0.4, 0.6])
    out, _ = assert_matches_reference(gs, camera(), seed, f"N={n}", background=bg)
    if n == 0:
        # Nothing blended: T stays exactly 1, so the image is the background, bit for bit.
        assert torch.equal(out.image, bg.view(3, 1, 1).expand_as(out.image))
        assert float(out.alpha.detach().abs().max()) == 0.0


def test_one_by_one_image(seed: int) -> None:
    """A 1x1 image with Gaussians covering and missing the single pixel."""
    gs = random_gaussians(10, seed, spread=0.05)
    assert_matches_reference(gs, camera(1, 1, fx=2.0), seed, "1x1")


def test_large_image_few_gaussians(seed: int) -> None:
    """4000x3000 with a handful of Gaussians: finite, and right where it is cheap to check."""
    gs = random_gaussians(4, seed, spread=0.3)
    gs.log_scales = gs.log_scales - 1.0
    cam = camera(4000, 3000, fx=2000.0, fy=2100.0)
    out, grads = render_with_grads(gs, cam, "cpu", seed)
    assert_finite(out, grads, "4000x3000")
    assert out.image.shape == (3, 3000, 4000)
    assert float(out.alpha.detach().max()) > 0, f"nothing drawn (seed {seed})"
    # The same scene seen through a camera cropped around the drawn pixels must agree.
    ys, xs = torch.nonzero(out.alpha.detach()[0] > 0, as_tuple=True)
    y0, x0 = int(ys.min()), int(xs.min())
    h, w = int(ys.max()) - y0 + 1, int(xs.max()) - x0 + 1
    if h * w <= 200_000:
        crop = camera(w, h, fx=2000.0, fy=2100.0, cx=2000.0 - x0, cy=1500.0 - y0)
        keep = ~decision_windows(gs, crop).pixels.expand(3, h, w)
        with torch.no_grad():
            exact = [t.double() for t in gs.tensors()]
            ref = rasterize_reference(
                RasterInputs(*exact, crop, torch.zeros(3, dtype=torch.float64), 0.01, 1e10, 0.3)
            )
            ref32 = rasterize_reference(RasterInputs(*gs.tensors(), crop, torch.zeros(3), 0.01,
                                                     1e10, 0.3), dtype=torch.float32)  # fmt: skip
        got = out.image.detach()[:, y0 : y0 + h, x0 : x0 + w]
        assert_float32_close(got[keep], ref.image[keep], ref32.image[keep],
                             float(ref.image.abs().max()), f"crop (seed {seed})")  # fmt: skip


def test_anisotropic_intrinsics_off_centre(seed: int) -> None:
    """fx != fy and a principal point far from the image centre."""
    gs = random_gaussians(40, seed)
    cam = camera(36, 28, fx=30.0, fy=55.0, cx=4.0, cy=25.0)
    assert_matches_reference(gs, cam, seed, "fx!=fy, off-centre")


def test_far_from_origin_camera_close(seed: int) -> None:
    """Gaussians and camera 1e4 units from the origin, the camera within a few units."""
    gs = random_gaussians(30, seed)
    offset = torch.tensor([1e4, -1e4, 1e4])
    gs = Gaussians(gs.means + offset, gs.log_scales, gs.quats, gs.opacity_logits, gs.features)
    pose = torch.eye(4)
    pose[:3, 3] = -offset  # world-to-camera: t = -R c with the camera centre at the offset
    out, _ = assert_matches_reference(gs, camera(pose=pose), seed, "far from origin")
    assert float(out.alpha.detach().max()) > 0, f"nothing drawn (seed {seed})"
