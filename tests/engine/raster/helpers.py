"""Scene builders and comparisons shared by the rasterizer tests.

Every numerical comparison here follows the float32 rule of ``tests/engine/numerics.py``: the
native kernel and torch's float32 run of the dense reference are both measured against the dense
reference in float64, and the kernel's error must stay within a small factor of torch's. The
rasterizer adds one thing the rule alone cannot handle: *decisions*. A pixel skips a Gaussian
whose alpha is below 1/255, stops before its transmittance falls to 1e-4, clamps alpha at
0.999, and blends in depth order; when the float64 value sits within float32's error of such a
threshold, float32 and float64 may decide differently and the pixel's value jumps by a whole
term. :func:`ambiguous_pixels` finds those pixels (a few per thousand), and the comparisons leave
them out of the outputs and out of the loss whose gradients are compared.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import torch
from torch import Tensor

from sparsesplat.api.cameras import Intrinsics
from sparsesplat.engine.camera import Camera
from sparsesplat.engine.raster import RasterOutput, rasterize
from sparsesplat.engine.raster.projection import ALPHA_THRESHOLD, Projected, project
from sparsesplat.engine.raster.reference import (
    MAX_ALPHA,
    MIN_TRANSMITTANCE,
    rasterize_reference,
)
from sparsesplat.engine.raster.types import RasterInputs
from tests.engine.numerics import (
    DECISION_SAFETY,
    FLOOR_ULPS,
    UNIT_ROUNDOFF,
    Float32Comparison,
    compare_float32,
    row_terms,
)

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
    """A pinhole camera; identity pose unless given, ``fy`` = ``fx`` and the principal point
    at the image centre unless given (the SDK's defaults)."""
    lens = Intrinsics.centred(fx, width, height, fy, cx, cy)
    pose = torch.eye(4) if pose is None else pose
    return Camera(pose, lens.fx, lens.fy, lens.cx, lens.cy, width, height)


NEAR, FAR, EPS2D = 0.01, 1e10, 0.3
"""rasterize()'s defaults for the depth range and the 2D dilation."""
AMBIGUOUS_SHARE = 0.1
"""At most this share of a test image's pixels (or one pixel) may be left out as ambiguous, else
the test would test nothing. Measured over 150 seeds per scene: random scenes up to 1.4 %, the
saturated one (most pixels stop at the 1e-4 transmittance threshold) up to 5.0 %."""


@dataclass
class Windows:
    """Where float32 may legitimately decide a threshold differently from float64."""

    pixels: Tensor
    """(H, W) bool: pixels with a blending decision within float32's error of its threshold."""
    gaussians: Tensor
    """(N,) bool: Gaussians whose culling (opacity, screen box) is within float32's error."""
    coverage: Tensor
    """(N,) float64: how many pixels blend each Gaussian (its gradient sums that many terms per
    output channel)."""


def _projected(gs: Gaussians, cam: Camera, dtype: torch.dtype, near: float, far: float,
               eps2d: float) -> Projected:  # fmt: skip
    """``project()`` of the first four tensors in ``dtype``, without autograd."""
    with torch.no_grad():
        m, s, q, o = (t.detach().to(dtype) for t in gs.tensors()[:4])
        return project(m, s, q, o, cam, near, far, eps2d)


def _error_bound(p32: Tensor, p64: Tensor, terms: Tensor, floor_ulps: float = FLOOR_ULPS) -> Tensor:
    """float32's error of a projected quantity, generously: DECISION_SAFETY times (torch's
    measured error plus ``floor_ulps`` roundoffs of the terms)."""
    measured = (p32.double() - p64).abs()
    return DECISION_SAFETY * (measured + floor_ulps * UNIT_ROUNDOFF * terms)


def _culling_windows(
    p64: Projected, dm: Tensor, dcon: Tensor, dlog_op: Tensor, cam: Camera
) -> tuple[Tensor, Tensor]:
    """(Gaussians whose culling is within float32's error of a threshold, Gaussians with a
    conic): the opacity threshold and the screen box, whose radius is ceil(ext sqrt(cov
    diagonal)) as in ``project()``. ``dm``, ``dcon``, ``dlog_op``: error bounds of the 2D
    centres, the conics and log-opacities."""
    m, con, op = p64.means2d, p64.conics, p64.opacities
    thr = ALPHA_THRESHOLD
    amb_g = (torch.log(op / thr)).abs() <= dlog_op
    # conic = (c, -b, a) / det of the covariance (a, b, c), so det(conic) = 1 / det.
    det_con = con[:, 0] * con[:, 2] - con[:, 1] ** 2
    has_con = (con != 0).any(-1) & (det_con > 0)
    cov_diag = torch.stack([con[:, 2], con[:, 0]], -1) / det_con.clamp_min(1e-300).unsqueeze(-1)
    ext = torch.sqrt(2.0 * torch.log(op.clamp_min(thr) / thr)).clamp(max=3.33).unsqueeze(-1)
    reach = ext * cov_diag.clamp_min(0).sqrt()
    rel_con = (dcon / row_terms(con).clamp_min(1e-300)).amax(-1, keepdim=True)
    reach_err = reach * (rel_con + dlog_op.unsqueeze(-1))
    radius = torch.ceil(reach)
    # A radius within its error of an integer may be one more or less.
    slack = ((reach - torch.round(reach)).abs() <= reach_err).double()
    size = torch.tensor([float(cam.width), float(cam.height)], dtype=torch.float64)
    edge = torch.minimum((m + radius).abs(), (m - radius - size).abs())
    amb_g |= has_con & ((edge <= dm + slack).any(-1))
    return amb_g, has_con


def _bounds(p64: Projected, p32: Projected) -> tuple[Tensor, Tensor, Tensor, Tensor]:
    """Error bounds (``_error_bound``) of the 2D centres, conics, log-opacities and depths."""
    m, con, op, z = p64.means2d, p64.conics, p64.opacities, p64.depths
    dm = _error_bound(p32.means2d, m, row_terms(m))
    dcon = _error_bound(p32.conics, con, row_terms(con))
    # Relative error of the opacity, i.e. absolute error of its log.
    dlog_op = _error_bound(p32.opacities, op, op) / op.clamp_min(1e-300)
    # z is R (m - c) from float32 inputs: 3 products and 2 sums, exact for the suite's poses.
    dz = _error_bound(p32.depths, z, z.abs(), floor_ulps=0.25)
    return dm, dcon, dlog_op, dz


def culling_windows(
    gs: Gaussians, cam: Camera, near: float = NEAR, far: float = FAR, eps2d: float = EPS2D
) -> Tensor:
    """(N,) bool: Gaussians whose culling (opacity threshold, screen box) float32 may decide
    differently from float64 (see :func:`decision_windows`)."""
    p64 = _projected(gs, cam, torch.float64, near, far, eps2d)
    p32 = _projected(gs, cam, torch.float32, near, far, eps2d)
    dm, dcon, dlog_op, _ = _bounds(p64, p32)
    return _culling_windows(p64, dm, dcon, dlog_op, cam)[0]


def decision_windows(
    gs: Gaussians, cam: Camera, near: float = NEAR, far: float = FAR, eps2d: float = EPS2D
) -> Windows:
    """Pixels and Gaussians whose float32 outcome may differ from float64's by a decision.

    The decisions are the reference's (``reference.composite_dense``): skip a pair with power
    < 0 or alpha < 1/255, clamp alpha at 0.999 (a kink: the gradient through it vanishes), stop
    before the pair that takes transmittance to 1e-4, blend in depth order; and cull a Gaussian
    with opacity < 1/255 or a screen box off the image. Each is evaluated in float64 with an
    error bound built from how far torch's float32 projection of the same Gaussian is from
    float64 (``_error_bound``), propagated to power, log-alpha and log-transmittance to first
    order. Depth-range culling is left out: the suite's poses are identity or translations, for
    which float32 z is float64 z rounded once, and rounding is monotonic.
    """
    p64 = _projected(gs, cam, torch.float64, near, far, eps2d)
    p32 = _projected(gs, cam, torch.float32, near, far, eps2d)
    m, con, op, z = p64.means2d, p64.conics, p64.opacities, p64.depths
    dm, dcon, dlog_op, dz = _bounds(p64, p32)
    amb_g, has_con = _culling_windows(p64, dm, dcon, dlog_op, cam)

    # Blending, densely over (pixel, Gaussian) pairs in depth order (ties by index).
    thr = ALPHA_THRESHOLD
    keep = ((p64.radii > 0).all(-1) | amb_g) & has_con & (z > 0)
    idx = torch.nonzero(keep).squeeze(-1)
    order = idx[torch.sort(z[idx], stable=True).indices]
    h, w = cam.height, cam.width
    vv, uu = torch.meshgrid(torch.arange(h, dtype=torch.float64) + 0.5,
                            torch.arange(w, dtype=torch.float64) + 0.5, indexing="ij")  # fmt: skip
    dx = m[order, 0] - uu.reshape(-1, 1)
    dy = m[order, 1] - vv.reshape(-1, 1)
    a, b, c = (con[order, k] for k in range(3))
    da, db, dc = (dcon[order, k] for k in range(3))
    power = 0.5 * (a * dx * dx + c * dy * dy) + b * dx * dy
    power_terms = 0.5 * (a.abs() * dx * dx + c.abs() * dy * dy) + (b * dx * dy).abs()
    err_p = (0.5 * (da * dx * dx + dc * dy * dy) + db * (dx * dy).abs()
             + (a * dx + b * dy).abs() * dm[order, 0] + (c * dy + b * dx).abs() * dm[order, 1]
             + DECISION_SAFETY * FLOOR_ULPS * UNIT_ROUNDOFF * power_terms)  # fmt: skip
    log_alpha = torch.log(op[order]) - power
    err_la = err_p + dlog_op[order]
    amb = (power.abs() <= err_p) | ((log_alpha - math.log(thr)).abs() <= err_la)
    amb |= (log_alpha - math.log(MAX_ALPHA)).abs() <= err_la
    alpha = torch.exp(log_alpha).clamp(max=MAX_ALPHA)
    used = (power >= 0) & (alpha >= thr)
    a_used = torch.where(used, alpha, 0.0)
    log_t = torch.cumsum(torch.log1p(-a_used), dim=1)
    # d log(1 - alpha) = alpha / (1 - alpha) * d log(alpha); a clamped alpha is exact.
    grow = torch.where(used & (alpha < MAX_ALPHA), a_used / (1 - a_used) * err_la, 0.0)
    err_t = torch.cumsum(grow, dim=1) + DECISION_SAFETY * FLOOR_ULPS * UNIT_ROUNDOFF
    amb |= used & ((log_t - math.log(MIN_TRANSMITTANCE)).abs() <= err_t)
    # Adjacent Gaussians in depth order closer than their depth errors may swap.
    zs, dzs = z[order], dz[order]
    tie = (zs[1:] - zs[:-1]).abs() <= dzs[1:] + dzs[:-1]
    swap = torch.zeros_like(used)
    swap[:, :-1] = used[:, :-1] & used[:, 1:] & tie
    amb |= swap
    # Only pairs a pixel reaches count: those after its stop do not enter its value.
    stop = used & (torch.exp(log_t) <= MIN_TRANSMITTANCE)
    reached = torch.cumsum(stop.to(torch.int32), dim=1) - stop.to(torch.int32) == 0
    pixels = (amb & reached).any(dim=1).reshape(h, w)
    coverage = torch.zeros(len(z), dtype=torch.float64)
    coverage[order] = (used & reached).sum(dim=0).double()
    return Windows(pixels, amb_g, coverage)


def loss_weights(out: RasterOutput, seed: int) -> tuple[Tensor, Tensor, Tensor]:
    """The seeded random weights (uniform in [0, 1)) of image, depth and alpha in the test loss."""
    g = torch.Generator().manual_seed(seed + 7)
    return tuple(torch.rand(t.shape, generator=g) for t in (out.image, out.depth, out.alpha))  # type: ignore[return-value]


def render_with_grads(
    gs: Gaussians, cam: Camera, backend: str, seed: int, background: Tensor | None = None,
    skip: Tensor | None = None, near: float = NEAR, far: float = FAR, eps2d: float = EPS2D,
    signs: int | None = None,
) -> tuple[RasterOutput, list[Tensor | None]]:  # fmt: skip
    """Render, back-propagate a seeded random linear loss of image, depth and alpha.

    ``backend``: ``"cpu"`` (the native kernel), ``"cuda"`` (gsplat; results come back to the
    CPU), ``"reference"`` (the dense reference in float64, inputs promoted, so outputs and
    gradients are float64) or ``"reference32"`` (the same dense code run by torch in float32: the
    scale of float32 rounding). ``skip`` ((H, W) bool) zeroes the loss weights there (pixels
    whose value depends on a float32 decision). ``signs``: a seed for random signs on every loss
    weight (see :func:`gradient_terms`).
    """
    dtype = torch.float64 if backend == "reference" else torch.float32
    device = "cuda" if backend == "cuda" else "cpu"
    leaves = [t.detach().to(dtype).clone().requires_grad_(True) for t in gs.tensors()]
    m, s, q, o, f = (t.to(device) for t in leaves)
    if backend == "reference32":
        bg32 = torch.zeros(f.shape[1]) if background is None else background.float()
        out = rasterize_reference(
            RasterInputs(m, s, q, o, f, cam, bg32, near, far, eps2d), dtype=torch.float32
        )
    else:
        bg = None if background is None else background.to(device, dtype)
        out = rasterize(m, s, q, o, f, cam.to(device), bg, near, far, eps2d, backend)
    if device != "cpu":
        out = RasterOutput(out.image.cpu(), out.depth.cpu(), out.alpha.cpu(), out.radii.cpu(),
                           out.means2d)  # fmt: skip
    weights = list(loss_weights(out, seed))
    if signs is not None:
        g = torch.Generator().manual_seed(signs)
        weights = [w * (torch.randint(0, 2, w.shape, generator=g) * 2 - 1) for w in weights]
    keep = 1.0 if skip is None else (~skip).to(dtype)
    loss = torch.zeros((), dtype=dtype)
    for value, w in zip((out.image, out.depth, out.alpha), weights, strict=True):
        loss = loss + (value * w.to(dtype) * keep).sum()
    if loss.requires_grad:
        loss.backward()
    return out, [p.grad for p in leaves]


SIGN_SAMPLES = 4
"""Random-sign renders that estimate the size of a gradient's per-pixel terms."""


def gradient_terms(
    gs: Gaussians, cam: Camera, seed: int, background: Tensor | None, windows: Windows,
    grads64: list[Tensor | None], near: float = NEAR, far: float = FAR, eps2d: float = EPS2D,
    means2d_grad64: Tensor | None = None,
) -> list[Tensor]:  # fmt: skip
    """Magnitude of the terms each gradient entry sums, for the float32 rule.

    A Gaussian's gradient is a sum over the pixels it covers of ``c_p = w_p d out_p / d theta``,
    and these terms cancel (left and right of a centre, in front of and behind a colour): the
    gradient can be ~0 while float32 summation keeps only ``u * sum |c_p|`` of it. With random
    signs ``s_p`` on the loss weights, ``E[(sum s_p c_p)^2] = sum c_p^2``, so a few float64
    renders estimate ``Q = sqrt(sum c_p^2)``, and ``sum |c_p| <= sqrt(n) Q`` (Cauchy-Schwarz)
    over the ``n`` terms: the pixels the Gaussian covers times the output channels. Returns
    ``|gradient| + sqrt(n) Q`` per entry (float64), one tensor per input of ``rasterize`` and,
    when ``means2d_grad64`` is given, one more for the 2D means' gradient.
    """
    like = [*gs.tensors(), gs.means[:, :2]]
    squares: list[Tensor] = [torch.zeros_like(t, dtype=torch.float64) for t in like]
    for k in range(SIGN_SAMPLES):
        out, flipped = render_with_grads(gs, cam, "reference", seed, background, windows.pixels,
                                         near, far, eps2d, signs=seed * 31 + k)  # fmt: skip
        for acc, g in zip(squares, [*flipped, out.means2d.grad], strict=True):
            if g is not None:
                acc += g.double().square()
    channels = gs.features.shape[1] + 2  # image channels, depth, alpha
    n = (windows.coverage * channels).clamp_min(1.0).sqrt()
    sizes = []
    wanted = [*grads64] + ([means2d_grad64] if means2d_grad64 is not None else [])
    for acc, g in zip(squares, wanted, strict=False):
        q = (acc / SIGN_SAMPLES).sqrt()
        size = torch.zeros_like(acc) if g is None else g.double().abs()
        sizes.append(size + n.reshape(-1, *[1] * (acc.dim() - 1)) * q)
    return sizes


def assert_finite(out: RasterOutput, grads: list[Tensor | None], what: str) -> None:
    """Every output and gradient is finite."""
    for name, t in (("image", out.image), ("depth", out.depth), ("alpha", out.alpha)):
        assert torch.isfinite(t).all(), f"{what}: non-finite {name}"
    for name, g in zip(PARAM_NAMES, grads, strict=True):
        assert g is None or torch.isfinite(g).all(), f"{what}: non-finite grad of {name}"


def _zeros_if_none(t: Tensor | None, like: Tensor) -> Tensor:
    """A missing gradient is a zero gradient."""
    return torch.zeros_like(like) if t is None else t


def jittered(gs: Gaussians, seed: int) -> Gaussians:
    """The same scene with every input moved by one float32 step up or down (random): another
    independent draw of float32 rounding for the same geometry."""
    g = torch.Generator().manual_seed(seed)

    def move(t: Tensor) -> Tensor:
        up = torch.rand(t.shape, generator=g) < 0.5
        return torch.where(up, torch.nextafter(t, t + 1), torch.nextafter(t, t - 1))

    return Gaussians(*[move(t) for t in gs.tensors()])


@dataclass
class ReferenceComparison:
    """The native kernel against the float64 reference on one scene (see
    :func:`compare_with_reference`)."""

    comparisons: list[Float32Comparison]
    """One per output (image, depth, alpha) and gradient, pooled over the draws."""
    out: RasterOutput
    """The kernel's render of the scene as given (the first draw)."""
    grads: list[Tensor | None]
    """Its gradients."""
    ref: RasterOutput
    """The float64 reference's render of the scene as given."""
    windows: Windows
    """The scene's decision windows."""


def compare_with_reference(
    gs: Gaussians, cam: Camera, seed: int, what: str, background: Tensor | None = None,
    draws: int = 1, perturb: tuple[str, int, float] | None = None,
    max_ambiguous: float = AMBIGUOUS_SHARE, backend: str = "cpu", near: float = NEAR,
    far: float = FAR, eps2d: float = EPS2D,
) -> ReferenceComparison:  # fmt: skip
    """Render with the native kernel (or gsplat: ``backend="cuda"``), the float64 reference and
    torch's float32 run of the reference; measure each output and gradient under the float32
    rule, pixels in :func:`decision_windows` left out.

    ``draws > 1`` repeats it on :func:`jittered` copies of the scene and pools the errors: a
    scene of a few ill-conditioned Gaussians has too few independent rounding draws for torch's
    error to be a stable scale. ``perturb = (name, flat_index, relative)`` multiplies one entry
    of one kernel output or gradient (first draw) by ``1 + relative``: tests of the check itself.
    """
    msg = f"{what} (seed {seed})"
    pooled: dict[str, list[list[Tensor]]] = {}
    first: tuple[RasterOutput, list[Tensor | None], RasterOutput, Windows] | None = None
    for draw in range(draws):
        scene = gs if draw == 0 else jittered(gs, seed + draw)
        windows = decision_windows(scene, cam, near, far, eps2d)
        skip = windows.pixels
        # One pixel may always sit at a threshold (a 1x1 image then checks only finiteness).
        count, allowed = int(skip.sum()), max(max_ambiguous * skip.numel(), 1.0)
        assert count <= allowed, f"{msg}: {count} of {skip.numel()} pixels sit at a threshold"
        ranges = (near, far, eps2d)
        out, grads = render_with_grads(scene, cam, backend, seed, background, skip, *ranges)
        ref, ref_grads = render_with_grads(scene, cam, "reference", seed, background, skip,
                                           *ranges)  # fmt: skip
        r32, grads32 = render_with_grads(scene, cam, "reference32", seed, background, skip,
                                         *ranges)  # fmt: skip
        assert_finite(out, grads, f"{msg} (cpu)")
        assert_finite(ref, ref_grads, f"{msg} (reference)")
        if first is None:
            first = (out, grads, ref, windows)
        for name in ("image", "depth", "alpha"):
            a, b, c = (getattr(o, name).detach() for o in (out, ref, r32))
            keep = ~skip.expand_as(b)
            # A pixel sums w_i f_i over its Gaussians plus T * background: the image's largest
            # value stands for the size of the terms (features may cancel).
            scale = torch.full_like(b[keep].double(), float(b.abs().max()) if b.numel() else 0.0)
            pooled.setdefault(name, []).append([a[keep], b[keep], c[keep], scale])
        sizes = gradient_terms(scene, cam, seed, background, windows, ref_grads, *ranges)
        for name, g, g64, g32, size in zip(PARAM_NAMES, grads, ref_grads, grads32, sizes,
                                           strict=True):  # fmt: skip
            like = scene.tensors()[PARAM_NAMES.index(name)].double()
            rows = [_zeros_if_none(t, like) for t in (g, g64, g32)]
            pooled.setdefault(f"grad of {name}", []).append([*rows, size])
    results = []
    for name, parts in pooled.items():
        got, ref64, ref32, terms = (torch.cat([p[k] for p in parts]) for k in range(4))
        if perturb is not None and name in (perturb[0], f"grad of {perturb[0]}"):
            got = got.clone()
            got.view(-1)[perturb[1]] *= 1 + perturb[2]
        results.append(compare_float32(got, ref64, ref32, terms, f"{msg}: {name}"))
    assert first is not None
    return ReferenceComparison(results, first[0], first[1], first[2], first[3])


def assert_matches_reference(
    gs: Gaussians, cam: Camera, seed: int, what: str, background: Tensor | None = None,
    draws: int = 1, max_ambiguous: float = AMBIGUOUS_SHARE, near: float = NEAR, far: float = FAR,
    eps2d: float = EPS2D,
) -> tuple[RasterOutput, list[Tensor | None]]:  # fmt: skip
    """The native kernel agrees with the float64 reference under the float32 rule
    (:func:`compare_with_reference`); culling agrees except for Gaussians at a culling
    threshold; radii agree to a pixel (a ceil). Returns the kernel's outputs and gradients."""
    res = compare_with_reference(gs, cam, seed, what, background, draws, None, max_ambiguous,
                                 near=near, far=far, eps2d=eps2d)  # fmt: skip
    for result in res.comparisons:
        assert result.passed, result.message()
    msg = f"{what} (seed {seed})"
    out, ref = res.out, res.ref
    sure = ~res.windows.gaussians
    assert torch.equal((out.radii > 0)[sure], (ref.radii > 0)[sure]), f"{msg}: culling differs"
    slack = (ref.radii.double() * 1e-5).clamp_min(1.0)
    differ = ((out.radii - ref.radii).abs() > slack) & sure
    assert not differ.any(), f"{msg}: radii differ at {torch.nonzero(differ).flatten().tolist()}"
    return out, res.grads
