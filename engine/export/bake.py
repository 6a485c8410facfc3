"""Bake a view-dependent colour function (the neural colour field) into 3DGS SH coefficients.

For each Gaussian we solve a linear least-squares problem: find c (K x 3) minimising
``sum_j w_j |Y(d_j) c + 0.5 - f(d_j)|^2`` over sampled view directions d_j, where Y is the real
SH basis of :mod:`sh_eval`. The 3DGS clamp at 0 is ignored by the fit; colours from the field
are in [0, 1] (up to the field's 0.001 margin), so it only matters where the fit undershoots.

Directions: a Fibonacci sphere (near-uniform, deterministic, full rank for K <= 16 once it has
more than 16 points), randomly rotated when a generator is given so repeated bakes do not share
blind spots. 64 directions: 4x more equations than the 16 unknowns of degree 3, which keeps the
aliasing of the field's higher frequencies into the fitted coefficients small, at the price of
64 evaluations of the colour head (two small matrix products per Gaussian each).

Sparse-view models are only ever seen from a narrow cone of directions, and the neural field is
unconstrained elsewhere; a uniform fit spends the SH budget there too. Passing ``view_dirs`` (the
directions from the training cameras to each Gaussian) adds those directions to each Gaussian's
equations with a chosen share of the total weight, so the bake is most faithful where the model
was trained and is still regularised by the whole sphere.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence

import torch
from torch import Tensor

from sparsesplat.engine.camera import Camera
from sparsesplat.engine.export.errors import ExportError
from sparsesplat.engine.export.sh_eval import MAX_DEGREE, eval_sh, num_coeffs, sh_basis

ColorFn = Callable[[Tensor], Tensor]
"""``dirs`` (N, 3) unit view directions, one per Gaussian -> RGB (N, 3) in [0, 1]."""


def fibonacci_sphere(
    n: int, generator: torch.Generator | None = None, dtype: torch.dtype = torch.float64
) -> Tensor:
    """``n`` near-uniform unit vectors (n, 3) on the sphere; randomly rotated if ``generator``."""
    i = torch.arange(n, dtype=dtype) + 0.5
    z = 1.0 - 2.0 * i / n
    r = torch.sqrt((1.0 - z * z).clamp_min(0.0))
    phi = i * math.pi * (3.0 - math.sqrt(5.0))  # golden angle steps
    pts = torch.stack([r * torch.cos(phi), r * torch.sin(phi), z], dim=1)
    if generator is not None:
        # Uniform random rotation: QR of a Gaussian matrix with the signs fixed (Haar measure).
        q, rr = torch.linalg.qr(torch.randn(3, 3, generator=generator, dtype=torch.float64))
        q = q * torch.sign(torch.diagonal(rr))
        if torch.det(q) < 0:
            q[:, 0] = -q[:, 0]
        pts = pts @ q.to(dtype).T
    return pts


def view_directions(means: Tensor, camera_centers: Tensor) -> Tensor:
    """Unit directions from each camera centre to each Gaussian: (N, 3), (V, 3) -> (N, V, 3)."""
    return torch.nn.functional.normalize(means[:, None, :] - camera_centers[None, :, :], dim=-1)


def _call(color_fn: ColorFn, dirs: Tensor, n: int, dtype: torch.dtype) -> Tensor:
    """Evaluate the colour function and check what it returns."""
    with torch.no_grad():
        rgb = color_fn(dirs)
    if not isinstance(rgb, Tensor) or tuple(rgb.shape) != (n, 3):
        shape = tuple(rgb.shape) if isinstance(rgb, Tensor) else type(rgb).__name__
        raise ExportError(f"bake_sh: color_fn returned {shape}, expected ({n}, 3)")
    return rgb.detach().to("cpu", dtype)


def bake_sh(
    color_fn: ColorFn,
    n_gaussians: int,
    degree: int = 3,
    n_dirs: int = 64,
    generator: torch.Generator | None = None,
    *,
    view_dirs: Tensor | None = None,
    view_weight: float = 1.0,
    device: torch.device | str = "cpu",
    chunk_size: int = 65536,
) -> Tensor:
    """Fit SH coefficients (N, (degree+1)^2, 3), float32 on CPU, to ``color_fn``.

    ``color_fn`` receives (N, 3) unit directions (camera -> Gaussian, the 3DGS convention) on
    ``device`` and returns RGB (N, 3). Without ``view_dirs`` every Gaussian shares the sampled
    directions and the fit is one pseudo-inverse applied in a streaming sum (memory O(N K)).
    With ``view_dirs`` (N, V, 3) the training directions get ``view_weight`` times the total
    weight of the sphere samples and each Gaussian solves its own K x K system, in chunks of
    ``chunk_size`` Gaussians. A field that is itself degree-``degree`` SH (and >= 0) is recovered
    exactly. Raises :class:`ExportError` on bad arguments.
    """
    if not 0 <= degree <= MAX_DEGREE:
        raise ExportError(f"bake_sh: degree must be in 0..3, got {degree}")
    k = num_coeffs(degree)
    if n_dirs < k:
        raise ExportError(f"bake_sh: n_dirs={n_dirs} < {k} coefficients of degree {degree}")
    if n_gaussians < 0:
        raise ExportError(f"bake_sh: n_gaussians must be >= 0, got {n_gaussians}")
    if view_dirs is not None and (
        view_dirs.dim() != 3 or view_dirs.shape[0] != n_gaussians or view_dirs.shape[2] != 3
    ):
        raise ExportError(
            f"bake_sh: view_dirs has shape {tuple(view_dirs.shape)}, expected ({n_gaussians}, V, 3)"
        )
    f64 = torch.float64
    sphere = fibonacci_sphere(n_dirs, generator)  # (D, 3)
    basis = sh_basis(sphere, degree)  # (D, K)
    # Accumulate b = sum_j w_j Y_j^T (f_j - 0.5) over the sphere with w_j = 1 / D.
    b = torch.zeros(n_gaussians, k, 3, dtype=f64)
    for j in range(n_dirs):
        d = sphere[j].to(device=device, dtype=torch.float32).expand(n_gaussians, 3).contiguous()
        target = _call(color_fn, d, n_gaussians, f64) - 0.5
        b += basis[j][None, :, None] * target[:, None, :] / n_dirs
    gram = basis.T @ basis / n_dirs  # (K, K), well conditioned for a Fibonacci set
    if view_dirs is None or view_dirs.shape[1] == 0 or view_weight <= 0:
        return torch.linalg.solve(gram, b).to(torch.float32)

    v = view_dirs.shape[1]
    unit = torch.nn.functional.normalize(view_dirs.detach().to("cpu", f64), dim=-1)
    w = view_weight / v
    view_basis = sh_basis(unit, degree)  # (N, V, K)
    for i in range(v):
        d = unit[:, i, :].to(device=device, dtype=torch.float32)
        target = _call(color_fn, d, n_gaussians, f64) - 0.5
        b += w * view_basis[:, i, :, None] * target[:, None, :]
    out = torch.empty(n_gaussians, k, 3, dtype=torch.float32)
    for start in range(0, n_gaussians, chunk_size):
        sl = slice(start, start + chunk_size)
        yb = view_basis[sl]
        a = gram + w * torch.einsum("nvk,nvl->nkl", yb, yb)
        out[sl] = torch.linalg.solve(a, b[sl]).to(torch.float32)
    return out


def _psnr(a: Tensor, b: Tensor) -> float:
    """PSNR in dB of two images in [0, 1] (inf when identical)."""
    mse = float(torch.mean((a.double() - b.double()) ** 2))
    return math.inf if mse == 0.0 else -10.0 * math.log10(mse)


def sh_baking_error(
    means: Tensor,
    log_scales: Tensor,
    quats: Tensor,
    opacity_logits: Tensor,
    sh: Tensor,
    neural_color_fn: Callable[[Camera], Tensor],
    cameras: Sequence[Camera],
    background: Tensor | None = None,
) -> float:
    """Mean PSNR (dB) over ``cameras`` of SH renders against neural-colour renders.

    Both renders use the same Gaussians through ``rasterize``; only the per-Gaussian colour
    differs: ``neural_color_fn(camera)`` -> (N, 3) versus ``sh`` (N, K, 3) evaluated along
    camera -> Gaussian directions. Images are clamped to [0, 1] before comparing, as they would
    be when saved. Higher is better; ``inf`` means identical renders.
    """
    from sparsesplat.engine.raster import rasterize  # the renderer is only needed here

    if not cameras:
        raise ExportError("sh_baking_error: no cameras given")
    psnrs = []
    with torch.no_grad():
        for cam in cameras:
            neural = neural_color_fn(cam)
            dirs = means - cam.center.to(means.device, means.dtype)
            sh_rgb = eval_sh(sh.to(means.device, means.dtype), dirs)
            args = (means, log_scales, quats, opacity_logits)
            ref = rasterize(*args, neural, cam, background=background).image
            got = rasterize(*args, sh_rgb, cam, background=background).image
            psnrs.append(_psnr(ref.clamp(0, 1), got.clamp(0, 1)))
    return sum(psnrs) / len(psnrs)
