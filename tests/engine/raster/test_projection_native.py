"""The native (C++) EWA projection against the torch ``project()`` it replaces on the CPU path.

Values are compared with ``project()`` run in float32 (the same float32 operations: agreement to
float32 rounding); gradients with autograd through ``project()`` run in float64, so the float32
rounding of both implementations is measured against the exact gradient of the same graph.
"""

from __future__ import annotations

import math
import random
from collections.abc import Callable
from dataclasses import dataclass

import pytest
import torch
from torch import Tensor

from sparsesplat.engine import native_build
from sparsesplat.engine.camera import Camera
from sparsesplat.engine.errors import RasterError
from sparsesplat.engine.raster import build, rasterize
from sparsesplat.engine.raster.cpu_backend import _Blend
from sparsesplat.engine.raster.native_projection import project_native
from sparsesplat.engine.raster.projection import Projected, project

from .helpers import camera, random_gaussians

INPUTS = ("means", "log_scales", "quats", "opacity_logits")
OUTPUTS = ("means2d", "conics", "depths", "opacities")
GRAD_RTOL = 1e-4
"""Per-element relative tolerance of the gradients against float64 autograd ..."""
GRAD_ATOL = 1e-5
"""... plus this fraction of the gradient tensor's largest entry: an entry that is a sum of
terms cancelling to ~0 keeps only float32's absolute precision of the terms (seen: 2e-6)."""
GRAD_L2 = 1e-5
"""Relative L2 error bound of each gradient tensor (seen: 5e-8 to 2e-6)."""


def _seed() -> int:
    return random.randrange(2**31)


@dataclass
class Case:
    """Projection inputs (float32) plus the arguments ``project()`` takes besides them."""

    params: list[Tensor]
    cam: Camera
    near: float = 0.01
    far: float = 1e10
    eps2d: float = 0.3


def _case(n: int, seed: int, spread: float = 0.8, cam: Camera | None = None) -> Case:
    gs = random_gaussians(n, seed, spread=spread)
    return Case([gs.means, gs.log_scales, gs.quats, gs.opacity_logits], cam or camera())


def _upstream(n: int, seed: int) -> list[Tensor]:
    """Random float64 gradients for means2d, conics, depths, opacities."""
    g = torch.Generator().manual_seed(seed + 1)
    shapes = [(n, 2), (n, 3), (n,), (n,)]
    return [torch.randn(s, generator=g, dtype=torch.float64) for s in shapes]


def _run(
    fn: Callable[..., Projected],
    case: Case,
    dtype: torch.dtype,
    up: list[Tensor],
    wanted: tuple[bool, ...],
) -> tuple[Projected, list[Tensor | None]]:
    """Project with ``fn`` in ``dtype``, back-propagate ``up``; returns outputs and input grads."""
    leaves = [
        p.detach().to(dtype).clone().requires_grad_(w)
        for p, w in zip(case.params, wanted, strict=True)
    ]
    c = case.cam
    cam = Camera(c.world_to_camera.to(dtype), c.fx, c.fy, c.cx, c.cy, c.width, c.height)
    out = fn(*leaves, cam, case.near, case.far, case.eps2d)
    outs = [getattr(out, name) for name in OUTPUTS]
    pairs = [(o, u.to(dtype)) for o, u in zip(outs, up, strict=True) if o.requires_grad]
    if pairs:
        torch.autograd.backward([o for o, _ in pairs], [u for _, u in pairs])
    return out, [leaf.grad for leaf in leaves]


def _l2(a: Tensor, ref: Tensor) -> float:
    """Relative L2 error of ``a`` against ``ref``."""
    return float((a.double() - ref).norm() / ref.norm().clamp_min(1e-300))


def _check(
    case: Case, seed: int, what: str, well_conditioned: bool = True
) -> tuple[Projected, list[Tensor | None]]:
    """Native values equal project()'s in float32 to rounding; native gradients equal float64
    autograd of project() to GRAD_RTOL / GRAD_ATOL (and GRAD_L2 when ``well_conditioned``;
    otherwise each gradient must be no further from float64 than 3x torch float32's own error).
    Culling, radii and exact zeros (masked rows) agree."""
    n = case.params[0].shape[0]
    up = _upstream(n, seed)
    everything = (True, True, True, True)
    got, grads = _run(project_native, case, torch.float32, up, everything)
    t32, grads32 = _run(project, case, torch.float32, up, everything)
    ref, grads64 = _run(project, case, torch.float64, up, everything)
    msg = f"{what} (seed {seed})"

    # Values: float32 rounding of the same operations (the GEMM's and exp's last bits differ).
    for name in ("means2d", "depths", "opacities"):
        a, b = getattr(got, name).detach().double(), getattr(t32, name).detach().double()
        assert a.dtype == b.dtype and a.shape == b.shape, msg
        assert torch.isfinite(a).all(), f"{msg}: non-finite {name}"
        err = float(((a - b).abs() - 1e-6 * b.abs()).max()) if a.numel() else 0.0
        assert err <= 0.0, f"{msg}: {name} differs from project() beyond rounding ({err:.3g})"
    a, b = got.conics.detach().double(), t32.conics.detach().double()
    assert torch.isfinite(a).all(), f"{msg}: non-finite conics"
    row = b.abs().amax(dim=-1, keepdim=True)
    err = float(((a - b).abs() / row.clamp_min(1e-300)).max()) if a.numel() else 0.0
    assert err < 1e-5, f"{msg}: conics differ from project() by {err:.3g} of the row"
    assert torch.equal((a == 0).all(-1), (b == 0).all(-1)), f"{msg}: conic culling differs"
    assert torch.equal(got.depths == 0, t32.depths == 0), f"{msg}: depth culling differs"
    assert got.radii.dtype == torch.int32 and got.radii.shape == (n, 2), msg
    assert torch.equal(got.radii > 0, t32.radii > 0), f"{msg}: culling differs from project()"
    assert torch.equal(got.radii > 0, ref.radii > 0), f"{msg}: culling differs from float64"
    # ceil(3.33 sqrt(a)) of a huge footprint may move by a pixel with the last bit of a.
    slack = (t32.radii.double() * 1e-5).clamp_min(1.0)
    assert ((got.radii - t32.radii).abs() <= slack).all(), f"{msg}: radii differ"

    for name, g, g32, g64 in zip(INPUTS, grads, grads32, grads64, strict=True):
        assert g is not None and g32 is not None and g64 is not None, msg
        assert g.dtype == torch.float32 and g.shape == g64.shape, msg
        assert torch.isfinite(g).all(), f"{msg}: non-finite grad of {name}"
        if name in ("log_scales", "quats"):
            # Only the conics depend on them, and torch.where masks culled rows: exact zeros.
            culled = (t32.conics == 0).all(-1)
            assert (g[culled] == 0).all(), f"{msg}: grad of {name} not zero on culled rows"
        if g.numel() == 0:
            continue
        e_native, e_torch32 = _l2(g, g64), _l2(g32, g64)
        if well_conditioned:
            bound = GRAD_ATOL * float(g64.abs().max())
            excess = float(((g.double() - g64).abs() - GRAD_RTOL * g64.abs() - bound).max())
            assert excess <= 0, f"{msg}: grad of {name} beyond rtol {GRAD_RTOL} (+{excess:.3g})"
            assert e_native < GRAD_L2, f"{msg}: grad of {name} rel L2 err {e_native:.3g}"
        else:
            assert e_native <= 3 * e_torch32 + GRAD_L2, (
                f"{msg}: grad of {name} rel L2 err {e_native:.3g} vs float32 torch {e_torch32:.3g}"
            )
    return got, grads


def test_random_gaussians_match_project() -> None:
    """Random Gaussians in front of the default camera, some outside the FoV clamp."""
    seed = _seed()
    _check(_case(300, seed), seed, "random")
    _check(_case(300, seed, spread=3.0), seed, "wide spread (FoV clamp active)")


def test_rotated_translated_camera() -> None:
    """A general world-to-camera pose: the rotation enters every gradient."""
    seed = _seed()
    g = torch.Generator().manual_seed(seed)
    q = torch.randn(4, generator=g, dtype=torch.float64)
    w, x, y, z = (q / q.norm()).tolist()
    rot = torch.tensor([
        [1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
        [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
        [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)],
    ], dtype=torch.float64)  # fmt: skip
    centre = torch.randn(3, generator=g, dtype=torch.float64) * 3
    pose = torch.eye(4, dtype=torch.float64)
    pose[:3, :3], pose[:3, 3] = rot, -rot @ centre
    case = _case(200, seed)
    # Same view-space layout as the default scene: world = R^T cam + centre.
    case.params[0] = (case.params[0].double() @ rot + centre).float()
    case.cam = camera(pose=pose.float())
    _check(case, seed, "rotated camera")


@pytest.mark.parametrize("scale", [1e-8, 1e4])
def test_extreme_scales(scale: float) -> None:
    """Points (eps2d keeps them a pixel wide) and Gaussians far larger than the image."""
    seed = _seed()
    case = _case(100, seed)
    case.params[1][:30] = math.log(scale)
    _check(case, seed, f"scale {scale}")


def test_needles() -> None:
    """Near-singular 2D covariances: one long axis, two of 1e-7."""
    seed = _seed()
    case = _case(100, seed)
    case.params[1][:, 1:] = math.log(1e-7)
    case.params[1][:, 0] = math.log(0.3)
    _check(case, seed, "needles, eps2d 0.3")
    # With eps2d 1e-4 the conics reach ~1e4 and float32 itself (torch's project() included)
    # keeps only ~4 digits of the log-scale gradient: held to torch float32's own error.
    case.eps2d = 1e-4
    _check(case, seed, "needles, eps2d 1e-4", well_conditioned=False)


def test_behind_camera_near_plane_and_beyond_far() -> None:
    """Culled by depth: zero conics/depths, zero scale/rotation grads, means2d still finite."""
    seed = _seed()
    case = _case(80, seed)
    means = case.params[0]
    means[:20, 2] = -torch.rand(20) * 5 - 0.1  # behind
    means[20, 2] = 0.01  # exactly on the near plane: culled (z > near is strict)
    means[21] = torch.tensor([0.01, -0.01, 0.0105])  # just past it
    means[22, 2] = 0.0  # in the camera plane
    means[23:35, 2] = 10 + torch.rand(12) * 5  # beyond far
    means[35, 2] = 10.0  # exactly at far
    case.far = 10.0
    got, grads = _check(case, seed, "behind / near / far")
    culled = torch.cat([torch.arange(0, 21), torch.arange(22, 36)])
    depths = got.depths.detach()
    assert (depths[culled] == 0).all() and (got.radii[culled] == 0).all(), f"seed {seed}"
    assert float(depths[21]) > 0, f"seed {seed}: z = 0.0105 culled"
    for g in grads[1:3]:
        assert g is not None and float(g[culled].abs().sum()) == 0.0, f"seed {seed}"
    # Culled centres still move in x/y through means2d (unmasked in project(), z = 1 stand-in),
    # but get nothing along z (identity pose: view z is world z), exactly as torch.where gives.
    assert grads[0] is not None and float(grads[0][culled, 2].abs().sum()) == 0.0, f"seed {seed}"
    assert float(grads[0][culled, :2].abs().sum()) > 0, f"seed {seed}"


def test_unnormalized_and_tiny_quaternions() -> None:
    """Quaternions of norm 1e3, 1e-6, below the 1e-12 clamp, and exactly zero."""
    seed = _seed()
    case = _case(120, seed)
    q = case.params[2]
    q[:30] *= 1e3
    q[30:60] *= 1e-6
    q[60:70] = q[60:70] / q[60:70].norm(dim=-1, keepdim=True) * 1e-13
    q[70] = 0.0
    _check(case, seed, "quaternion norms")


@pytest.mark.parametrize("logit", [30.0, -30.0])
def test_extreme_opacity_logits(logit: float) -> None:
    """sigmoid(30) rounds to 1 in float32 (zero grad there, as in torch); sigmoid(-30) culls."""
    seed = _seed()
    case = _case(60, seed)
    case.params[3][:20] = logit
    got, _ = _check(case, seed, f"logit {logit}")
    if logit < 0:
        assert (got.radii[:20] == 0).all(), f"seed {seed}"


def test_far_from_origin_camera_close() -> None:
    """Gaussians and camera 1e4 units from the origin: m - c must be formed in float64."""
    seed = _seed()
    offset = torch.tensor([1e4, -1e4, 1e4])
    pose = torch.eye(4)
    pose[:3, 3] = -offset
    case = _case(100, seed, cam=camera(pose=pose))
    case.params[0] = case.params[0] + offset
    got, _ = _check(case, seed, "far from origin")
    assert int((got.radii > 0).sum()) > 50, f"seed {seed}: nothing projected"


def test_anisotropic_intrinsics_off_centre() -> None:
    """fx != fy and a principal point far from the image centre (asymmetric FoV clamp)."""
    seed = _seed()
    cam = camera(36, 28, fx=30.0, fy=55.0, cx=4.0, cy=25.0)
    _check(_case(200, seed, spread=1.5, cam=cam), seed, "fx != fy, off-centre")


@pytest.mark.parametrize("n", [0, 1, 7, 9])
def test_small_counts(n: int) -> None:
    """N = 0 and 1, and counts around the 8-lane vector width (partial vectors)."""
    seed = _seed()
    case = _case(n, seed)
    if n:
        case.params[0][0] = torch.tensor([0.05, -0.02, 2.0])
    got, _ = _check(case, seed, f"N={n}")
    assert got.means2d.shape == (n, 2) and got.conics.shape == (n, 3), f"seed {seed}"


def test_non_contiguous_inputs() -> None:
    """Strided views are accepted (copied to contiguous) and give the same result."""
    seed = _seed()
    case = _case(50, seed)
    ref = project_native(*case.params, case.cam, 0.01, 1e10, 0.3)
    strided = [torch.stack([p, p], dim=-1)[..., 0] for p in case.params]
    assert not any(p.is_contiguous() for p in strided)
    got = project_native(*strided, case.cam, 0.01, 1e10, 0.3)
    for name in OUTPUTS:
        assert torch.equal(getattr(got, name), getattr(ref, name)), f"{name} (seed {seed})"


def test_partial_needs_grad_match_full_backward() -> None:
    """The soft-depth pass (only opacity logits) and the hard-depth pass (only means) get the
    same gradients as the full backward, and outputs that depend on no input needing grad do not
    require grad (so the blend skips their gradients)."""
    seed = _seed()
    case = _case(200, seed)
    up = _upstream(200, seed)
    _, full = _run(project_native, case, torch.float32, up, (True, True, True, True))
    soft, only_op = _run(project_native, case, torch.float32, up, (False, False, False, True))
    assert only_op[:3] == [None, None, None], f"seed {seed}"
    assert only_op[3] is not None and full[3] is not None
    assert torch.equal(only_op[3], full[3]), f"seed {seed}: opacity grads differ"
    assert soft.opacities.requires_grad, f"seed {seed}"
    assert not any(t.requires_grad for t in (soft.means2d, soft.conics, soft.depths, soft.radii))
    hard, only_m = _run(project_native, case, torch.float32, up, (True, False, False, False))
    assert only_m[1:] == [None, None, None], f"seed {seed}"
    assert only_m[0] is not None and full[0] is not None
    assert torch.equal(only_m[0], full[0]), f"seed {seed}: means grads differ"
    assert hard.means2d.requires_grad and hard.conics.requires_grad, f"seed {seed}"
    assert not hard.opacities.requires_grad, f"seed {seed}"
    with torch.no_grad():
        out = project_native(*case.params, case.cam, 0.01, 1e10, 0.3)
    assert not out.means2d.requires_grad


def test_rasterize_cpu_matches_torch_projection_pipeline() -> None:
    """rasterize(backend='cpu') renders and differentiates like the blend fed by project(),
    and means2d keeps its retained gradient (densification reads it)."""
    seed = _seed()
    gs = random_gaussians(120, seed)
    cam = camera(41, 33)
    gen = torch.Generator().manual_seed(seed + 3)
    weights = [torch.rand(3, 33, 41, generator=gen), torch.rand(1, 33, 41, generator=gen)]

    def loss_of(image: Tensor, depth: Tensor) -> Tensor:
        return (image * weights[0]).sum() + (depth * weights[1]).sum()

    params = [t.clone().requires_grad_(True) for t in gs.tensors()]
    out = rasterize(*params, cam, backend="cpu")
    loss_of(out.image, out.depth).backward()
    assert out.means2d.grad is not None, f"seed {seed}: means2d.grad not retained"

    leaves = [t.clone().requires_grad_(True) for t in gs.tensors()]
    proj = project(*leaves[:4], cam, 0.01, 1e10, 0.3)
    proj.means2d.retain_grad()
    parts = [proj.means2d, proj.conics, proj.opacities, proj.depths, leaves[4], torch.zeros(3)]
    image, depth, _, _ = _Blend.apply(*[t.contiguous() for t in parts], proj.radii, 41, 33)
    loss_of(image, depth).backward()
    assert proj.means2d.grad is not None

    assert torch.allclose(out.image, image, rtol=1e-5, atol=1e-6), f"seed {seed}"
    assert torch.allclose(out.depth, depth, rtol=1e-5, atol=1e-6), f"seed {seed}"
    assert torch.equal(out.radii, proj.radii.amax(-1)), f"seed {seed}"
    scale = float(proj.means2d.grad.abs().max())
    assert torch.allclose(out.means2d.grad, proj.means2d.grad, rtol=1e-4, atol=1e-6 * scale)
    for name, a, b in zip(("means", "log_scales", "quats", "opacity_logits", "features"),
                          params, leaves, strict=True):  # fmt: skip
        assert a.grad is not None and b.grad is not None, name
        tol = 1e-6 * float(b.grad.abs().max())
        assert torch.allclose(a.grad, b.grad, rtol=1e-4, atol=tol), f"{name} (seed {seed})"


def test_build_failure_raises_raster_error(monkeypatch: pytest.MonkeyPatch) -> None:
    """A failed build of the projection surfaces as RasterError with the compiler's output."""
    from torch.utils import cpp_extension

    def broken(**kwargs: object) -> None:
        raise RuntimeError("project.cpp:1:1: error: expected unqualified-id")

    monkeypatch.setattr(build._PROJECTION, "_module", None)
    monkeypatch.setattr(cpp_extension, "load", broken)
    assert isinstance(build._PROJECTION, native_build.NativeExtension)
    with pytest.raises(RasterError, match="expected unqualified-id"):
        build.load_projection_extension()
    gs = random_gaussians(3, 0)
    with pytest.raises(RasterError, match="CPU projection"):
        rasterize(*gs.tensors(), camera(), backend="cpu")
