"""The native (C++) EWA projection against the torch ``project()`` it replaces on the CPU path.

Values and gradients follow the float32 rule of ``tests/engine/numerics.py``: the native kernel
and torch's ``project()`` in float32 are both measured against ``project()`` run in float64 on
the same float32 inputs (autograd of the same graph for the gradients), and the kernel's error
must stay within 4x of torch's pooled error plus a floor of a few dozen roundoffs of each row.
The two float32 paths are never compared with each other: they round differently (a GEMM, an
exp), and which of them is closer to float64 depends on the CPU.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, field

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
from sparsesplat.engine.raster.types import RasterOutput
from tests.engine.numerics import Float32Comparison, assert_float32_close, compare_float32

from .helpers import (
    PARAM_NAMES,
    Gaussians,
    camera,
    culling_windows,
    decision_windows,
    gradient_terms,
    jittered,
    loss_weights,
    random_gaussians,
)

INPUTS = ("means", "log_scales", "quats", "opacity_logits")
OUTPUTS = ("means2d", "conics", "depths", "opacities")


@dataclass
class Case:
    """Projection inputs (float32) plus the arguments ``project()`` takes besides them."""

    params: list[Tensor]
    cam: Camera
    near: float = 0.01
    far: float = 1e10
    eps2d: float = 0.3
    draws: int = 1
    """Copies of the case (inputs moved by one float32 step) pooled in the comparison: a handful
    of Gaussians is too few rounding draws for torch's error to be a stable scale."""
    perturb: tuple[str, int, float] | None = field(default=None)
    """(output or input name, flat index, relative): spoil one native entry (tests of the check)."""


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
    params: list[Tensor] | None = None,
) -> tuple[Projected, list[Tensor | None]]:
    """Project with ``fn`` in ``dtype``, back-propagate ``up``; returns outputs and input grads."""
    leaves = [
        p.detach().to(dtype).clone().requires_grad_(w)
        for p, w in zip(case.params if params is None else params, wanted, strict=True)
    ]
    c = case.cam
    cam = Camera(c.world_to_camera.to(dtype), c.fx, c.fy, c.cx, c.cy, c.width, c.height)
    out = fn(*leaves, cam, case.near, case.far, case.eps2d)
    outs = [getattr(out, name) for name in OUTPUTS]
    pairs = [(o, u.to(dtype)) for o, u in zip(outs, up, strict=True) if o.requires_grad]
    if pairs:
        torch.autograd.backward([o for o, _ in pairs], [u for _, u in pairs])
    return out, [leaf.grad for leaf in leaves]


def _compare(case: Case, seed: int, what: str) -> tuple[list[Float32Comparison], Projected,
                                                          list[Tensor | None]]:  # fmt: skip
    """The float32 rule for the four outputs and four input gradients, pooled over
    ``case.draws`` jittered copies; returns the comparisons and the first copy's native run."""
    n = case.params[0].shape[0]
    up = _upstream(n, seed)
    everything = (True, True, True, True)
    pooled: dict[str, list[tuple[Tensor, Tensor, Tensor]]] = {}
    first: tuple[Projected, list[Tensor | None]] | None = None
    for draw in range(case.draws):
        params = case.params
        if draw:
            moved = jittered(Gaussians(*params, torch.zeros(n, 0)), seed + draw)
            params = moved.tensors()[:4]
        got, grads = _run(project_native, case, torch.float32, up, everything, params)
        t32, grads32 = _run(project, case, torch.float32, up, everything, params)
        ref, grads64 = _run(project, case, torch.float64, up, everything, params)
        if first is None:
            first = (got, grads)
        for name in OUTPUTS:
            trio = tuple(getattr(o, name).detach() for o in (got, ref, t32))
            pooled.setdefault(name, []).append(trio)  # type: ignore[arg-type]
        for name, g, g64, g32 in zip(INPUTS, grads, grads64, grads32, strict=True):
            assert g is not None and g64 is not None and g32 is not None, what
            assert g.dtype == torch.float32 and g.shape == g64.shape, what
            pooled.setdefault(f"grad of {name}", []).append((g, g64, g32))
    results = []
    for name, parts in pooled.items():
        a, b, c = (torch.cat([p[k] for p in parts]) for k in range(3))
        if case.perturb is not None and name in (case.perturb[0], f"grad of {case.perturb[0]}"):
            a = a.clone()
            a.view(-1)[case.perturb[1]] *= 1 + case.perturb[2]
        # Default terms: each Gaussian's row (largest |entry|), or the entry for vectors.
        results.append(compare_float32(a, b, c, None, f"{what} (seed {seed}): {name}"))
    assert first is not None
    return results, first[0], first[1]


def _check(case: Case, seed: int, what: str) -> tuple[Projected, list[Tensor | None]]:
    """Native outputs and gradients follow the float32 rule against float64 ``project()``.
    Culling agrees with float64 except within float32's error of a threshold, radii to a pixel
    (a ceil); culled rows get exact zeros, as the torch.where masks give."""
    results, got, grads = _compare(case, seed, what)
    for result in results:
        assert result.passed, result.message()
    n = case.params[0].shape[0]
    msg = f"{what} (seed {seed})"
    ref, _ = _run(project, case, torch.float64, _upstream(n, seed), (False,) * 4)
    for name in OUTPUTS:
        assert torch.isfinite(getattr(got, name)).all(), f"{msg}: non-finite {name}"
    gs = Gaussians(*case.params, torch.zeros(n, 0))
    sure = ~culling_windows(gs, case.cam, case.near, case.far, case.eps2d)
    conic_zero = (got.conics == 0).all(-1)
    assert torch.equal(conic_zero[sure], (ref.conics == 0).all(-1)[sure]), f"{msg}: conic culling"
    assert torch.equal((got.depths == 0)[sure], (ref.depths == 0)[sure]), f"{msg}: depth culling"
    assert got.radii.dtype == torch.int32 and got.radii.shape == (n, 2), msg
    assert torch.equal((got.radii > 0)[sure], (ref.radii > 0)[sure]), f"{msg}: culling differs"
    # ceil(3.33 sqrt(a)) of a huge footprint may move by a pixel with the last bit of a.
    slack = (ref.radii.double() * 1e-5).clamp_min(1.0)
    assert (((got.radii - ref.radii).abs() <= slack) | ~sure.unsqueeze(-1)).all(), f"{msg}: radii"
    for name, g in zip(INPUTS, grads, strict=True):
        assert g is not None and torch.isfinite(g).all(), f"{msg}: non-finite grad of {name}"
        if name in ("log_scales", "quats"):
            # Only the conics depend on them, and torch.where masks culled rows: exact zeros.
            assert (g[conic_zero] == 0).all(), f"{msg}: grad of {name} not zero on culled rows"
    return got, grads


def test_random_gaussians_match_project(seed: int) -> None:
    """Random Gaussians in front of the default camera, some outside the FoV clamp."""
    _check(_case(300, seed), seed, "random")
    _check(_case(300, seed, spread=3.0), seed, "wide spread (FoV clamp active)")


def test_rotated_translated_camera(seed: int) -> None:
    """A general world-to-camera pose: the rotation enters every gradient."""
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
def test_extreme_scales(scale: float, seed: int) -> None:
    """Points (eps2d keeps them a pixel wide) and Gaussians far larger than the image."""
    case = _case(100, seed)
    case.params[1][:30] = math.log(scale)
    _check(case, seed, f"scale {scale}")


def test_needles(seed: int) -> None:
    """Near-singular 2D covariances: one long axis, two of 1e-7."""
    case = _case(100, seed)
    case.params[1][:, 1:] = math.log(1e-7)
    case.params[1][:, 0] = math.log(0.3)
    _check(case, seed, "needles, eps2d 0.3")
    # With eps2d 1e-4 the conics reach ~1e4 and float32 itself (torch's project() included)
    # keeps only ~4 digits of the log-scale gradient: held to torch float32's own error.
    case.eps2d = 1e-4
    _check(case, seed, "needles, eps2d 1e-4")


def test_behind_camera_near_plane_and_beyond_far(seed: int) -> None:
    """Culled by depth: zero conics/depths, zero scale/rotation grads, means2d still finite."""
    case = _case(80, seed)
    means = case.params[0]
    g = torch.Generator().manual_seed(seed + 2)
    means[:20, 2] = -torch.rand(20, generator=g) * 5 - 0.1  # behind
    means[20, 2] = 0.01  # exactly on the near plane: culled (z > near is strict)
    means[21] = torch.tensor([0.01, -0.01, 0.0105])  # just past it
    means[22, 2] = 0.0  # in the camera plane
    means[23:35, 2] = 10 + torch.rand(12, generator=g) * 5  # beyond far
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


def test_unnormalized_and_tiny_quaternions(seed: int) -> None:
    """Quaternions of norm 1e3, 1e-6, below the 1e-12 clamp, and exactly zero."""
    case = _case(120, seed)
    q = case.params[2]
    q[:30] *= 1e3
    q[30:60] *= 1e-6
    q[60:70] = q[60:70] / q[60:70].norm(dim=-1, keepdim=True) * 1e-13
    q[70] = 0.0
    _check(case, seed, "quaternion norms")


@pytest.mark.parametrize("logit", [30.0, -30.0])
def test_extreme_opacity_logits(logit: float, seed: int) -> None:
    """sigmoid(30) rounds to 1 in float32 (zero grad there, as in torch); sigmoid(-30) culls."""
    case = _case(60, seed)
    case.params[3][:20] = logit
    got, _ = _check(case, seed, f"logit {logit}")
    if logit < 0:
        assert (got.radii[:20] == 0).all(), f"seed {seed}"


def test_far_from_origin_camera_close(seed: int) -> None:
    """Gaussians and camera 1e4 units from the origin: m - c must be formed in float64."""
    offset = torch.tensor([1e4, -1e4, 1e4])
    pose = torch.eye(4)
    pose[:3, 3] = -offset
    case = _case(100, seed, cam=camera(pose=pose))
    case.params[0] = case.params[0] + offset
    got, _ = _check(case, seed, "far from origin")
    assert int((got.radii > 0).sum()) > 50, f"seed {seed}: nothing projected"


def test_anisotropic_intrinsics_off_centre(seed: int) -> None:
    """fx != fy and a principal point far from the image centre (asymmetric FoV clamp)."""
    cam = camera(36, 28, fx=30.0, fy=55.0, cx=4.0, cy=25.0)
    _check(_case(200, seed, spread=1.5, cam=cam), seed, "fx != fy, off-centre")


@pytest.mark.parametrize("n", [0, 1, 7, 9])
def test_small_counts(n: int, seed: int) -> None:
    """N = 0 and 1, and counts around the 8-lane vector width (partial vectors)."""
    case = _case(n, seed)
    if n:
        case.params[0][0] = torch.tensor([0.05, -0.02, 2.0])
    # A few Gaussians are a few rounding draws: pool 16 jittered copies for a stable scale.
    case.draws = 16
    got, _ = _check(case, seed, f"N={n}")
    assert got.means2d.shape == (n, 2) and got.conics.shape == (n, 3), f"seed {seed}"


def test_non_contiguous_inputs(seed: int) -> None:
    """Strided views are accepted (copied to contiguous) and give the same result."""
    case = _case(50, seed)
    ref = project_native(*case.params, case.cam, 0.01, 1e10, 0.3)
    strided = [torch.stack([p, p], dim=-1)[..., 0] for p in case.params]
    assert not any(p.is_contiguous() for p in strided)
    got = project_native(*strided, case.cam, 0.01, 1e10, 0.3)
    for name in OUTPUTS:
        assert torch.equal(getattr(got, name), getattr(ref, name)), f"{name} (seed {seed})"


def test_partial_needs_grad_match_full_backward(seed: int) -> None:
    """The soft-depth pass (only opacity logits) and the hard-depth pass (only means) get the
    same gradients as the full backward, and outputs that depend on no input needing grad do not
    require grad (so the blend skips their gradients). Bit for bit: one kernel, one CPU, the
    same operations on each entry; the flags only skip whole outputs."""
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


@pytest.mark.parametrize(
    ("target", "relative"),
    [("means2d", 1e-3), ("conics", -1e-3), ("quats", 1e-3), ("log_scales", -2.0)],
)
def test_the_check_catches_one_wrong_entry(target: str, relative: float, seed: int) -> None:
    """The comparison is not vacuous: one output or gradient entry of the native kernel off by
    1e-3 of itself (or its sign flipped: -2 relative) fails it, where the kernel as is passes."""
    case = _case(300, seed)
    clean, got, grads = _compare(case, seed, "clean")
    assert all(r.passed for r in clean), [r.message() for r in clean]
    values = getattr(got, target) if target in OUTPUTS else grads[INPUTS.index(target)]
    assert values is not None
    case.perturb = (target, int(values.detach().abs().flatten().argmax()), relative)
    spoiled, _, _ = _compare(case, seed, "spoiled")
    failed = [r.what for r in spoiled if not r.passed]
    name = target if target in OUTPUTS else f"grad of {target}"
    assert failed == [f"spoiled (seed {seed}): {name}"], failed


def test_rasterize_cpu_matches_torch_projection_pipeline(seed: int) -> None:
    """rasterize(backend='cpu'), the native projection feeding the native blend, against the
    float64 dense reference under the float32 rule, with the same blend fed by torch's
    project() as the float32 scale: the native projection costs no more accuracy than torch's.
    means2d keeps its retained gradient (densification reads it), also within the rule."""
    gs = random_gaussians(120, seed)
    cam = camera(41, 33)
    windows = decision_windows(gs, cam)
    keep = (~windows.pixels).double()

    def loss_of(image: Tensor, depth: Tensor, alpha: Tensor) -> Tensor:
        # The loss of helpers.render_with_grads (gradient_terms measures its terms).
        weights = loss_weights(RasterOutput(image, depth, alpha, torch.zeros(0), image), seed)
        return sum(((o * w.to(o.dtype) * keep.to(o.dtype)).sum()
                    for o, w in zip((image, depth, alpha), weights, strict=True)),
                   torch.zeros((), dtype=image.dtype))  # fmt: skip

    params = [t.clone().requires_grad_(True) for t in gs.tensors()]
    out = rasterize(*params, cam, backend="cpu")
    loss_of(out.image, out.depth, out.alpha).backward()
    assert out.means2d.grad is not None, f"seed {seed}: means2d.grad not retained"

    leaves = [t.clone().requires_grad_(True) for t in gs.tensors()]
    proj = project(*leaves[:4], cam, 0.01, 1e10, 0.3)
    proj.means2d.retain_grad()
    parts = [proj.means2d, proj.conics, proj.opacities, proj.depths, leaves[4], torch.zeros(3)]
    image, depth, alpha, _, _ = _Blend.apply(*[t.contiguous() for t in parts], proj.radii, 41, 33)
    loss_of(image, depth, alpha).backward()
    assert proj.means2d.grad is not None

    exact = [t.double().requires_grad_(True) for t in gs.tensors()]
    ref = rasterize(*exact, cam, backend="reference")
    loss_of(ref.image, ref.depth, ref.alpha).backward()
    assert ref.means2d.grad is not None
    sizes = gradient_terms(gs, cam, seed, None, windows, [t.grad for t in exact],
                           means2d_grad64=ref.means2d.grad)  # fmt: skip

    msg = f"seed {seed}"
    mask = keep.bool()
    for name, a, b, c in (("image", out.image, ref.image, image),
                          ("depth", out.depth, ref.depth, depth),
                          ("alpha", out.alpha, ref.alpha, alpha)):  # fmt: skip
        m = mask.expand_as(b)
        scale = float(b.detach().abs().max())
        assert_float32_close(a.detach()[m], b.detach()[m], c.detach()[m], scale, f"{name} {msg}")
    assert_float32_close(out.means2d.grad, ref.means2d.grad, proj.means2d.grad, sizes[-1],
                         what=f"means2d.grad {msg}")  # fmt: skip
    for name, a, b, c, size in zip(PARAM_NAMES, params, exact, leaves, sizes, strict=False):
        assert a.grad is not None and b.grad is not None and c.grad is not None, name
        assert_float32_close(a.grad, b.grad, c.grad, size, f"grad of {name} {msg}")
    sure = ~windows.gaussians
    assert torch.equal((out.radii > 0)[sure], (ref.radii > 0)[sure]), f"{msg}: culling differs"
    slack = (ref.radii.double() * 1e-5).clamp_min(1.0)
    assert (((out.radii - ref.radii).abs() <= slack) | ~sure).all(), f"{msg}: radii differ"


def test_build_failure_raises_raster_error_and_rendering_falls_back(
    monkeypatch: pytest.MonkeyPatch, caplog: pytest.LogCaptureFixture
) -> None:
    """A failed build of the projection surfaces as RasterError with the compiler's output
    from its loader; a render warns once, naming the torch projection it uses instead, and
    still renders (the tile kernels are built)."""
    from torch.utils import cpp_extension

    def broken(**kwargs: object) -> None:
        raise RuntimeError("project.cpp:1:1: error: expected unqualified-id")

    build.load_extension()  # the tile kernels, built before the compiler breaks
    # Both restored after the test: the failure must not outlive it in this process.
    monkeypatch.setattr(build._PROJECTION, "_module", None)
    monkeypatch.setattr(build._PROJECTION, "_failure", None)
    monkeypatch.setattr(cpp_extension, "load", broken)
    assert isinstance(build._PROJECTION, native_build.NativeExtension)
    with pytest.raises(RasterError, match="expected unqualified-id"):
        build.load_projection_extension()
    gs = random_gaussians(3, 0)
    with caplog.at_level("WARNING"):
        out = rasterize(*gs.tensors(), camera(), backend="cpu")
        rasterize(*gs.tensors(), camera(), backend="cpu")
    warned = [r.getMessage() for r in caplog.records if "could not be built" in r.getMessage()]
    assert len(warned) == 1 and "the CPU projection" in warned[0], warned
    assert "torch implementation" in warned[0] and "expected unqualified-id" in warned[0]
    assert out.stats is not None  # the native tile kernels ran
