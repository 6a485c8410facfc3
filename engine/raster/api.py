"""The one rendering entry point: validates inputs and dispatches to a backend."""

from __future__ import annotations

import math

import torch
from torch import Tensor

from sparsesplat.engine.camera import Camera
from sparsesplat.engine.errors import RasterError
from sparsesplat.engine.raster.types import RasterInputs, RasterOutput

BACKENDS = ("auto", "cpu", "cuda", "reference")
"""Accepted values of ``rasterize(backend=...)``."""


def _check_tensor(name: str, t: object, shape: tuple[int | None, ...]) -> Tensor:
    """Raise RasterError unless ``t`` is a floating tensor of the given shape (None = any)."""
    if not isinstance(t, Tensor):
        raise RasterError(f"{name}: expected a torch.Tensor, got {type(t).__name__}")
    if not t.is_floating_point():
        raise RasterError(f"{name}: expected a floating-point tensor, got dtype {t.dtype}")
    dims_ok = t.dim() == len(shape)
    if not dims_ok or any(s is not None and s != d for s, d in zip(shape, t.shape, strict=False)):
        want = "(" + ", ".join("*" if s is None else str(s) for s in shape) + ")"
        raise RasterError(f"{name}: expected shape {want}, got {tuple(t.shape)}")
    return t


def _validate(args: RasterInputs, backend: str) -> RasterInputs:
    """Check every argument; returns them with the background a tensor (zeros when None)."""
    means, log_scales, quats, opacity_logits, features, camera, background, near, far, eps2d = args
    n = _check_tensor("means", means, (None, 3)).shape[0]
    _check_tensor("log_scales", log_scales, (n, 3))
    _check_tensor("quats", quats, (n, 4))
    _check_tensor("opacity_logits", opacity_logits, (n,))
    c = _check_tensor("features", features, (n, None)).shape[1]
    named = {"log_scales": log_scales, "quats": quats, "opacity_logits": opacity_logits}
    named["features"] = features
    for name, t in named.items():
        if t.device != means.device:
            raise RasterError(f"{name}: on {t.device}, but means is on {means.device}")
        if t.dtype != means.dtype:
            raise RasterError(f"{name}: dtype {t.dtype} differs from means dtype {means.dtype}")
    if not isinstance(camera, Camera):
        raise RasterError(f"camera: expected a Camera, got {type(camera).__name__}")
    for attr in ("fx", "fy"):
        v = float(getattr(camera, attr))
        if not (math.isfinite(v) and v > 0):
            raise RasterError(f"camera.{attr}: must be finite and > 0, got {v}")
    for attr in ("cx", "cy"):
        if not math.isfinite(float(getattr(camera, attr))):
            raise RasterError(f"camera.{attr}: must be finite")
    if int(camera.width) < 1 or int(camera.height) < 1:
        raise RasterError(f"camera: image size must be >= 1x1, got {camera.width}x{camera.height}")
    pose = camera.world_to_camera
    if not isinstance(pose, Tensor) or tuple(pose.shape) != (4, 4):
        raise RasterError("camera.world_to_camera: expected a (4, 4) tensor")
    if not bool(torch.isfinite(pose).all()):
        raise RasterError("camera.world_to_camera: contains non-finite values")
    if not (math.isfinite(near) and near > 0 and far > near):
        raise RasterError(f"near/far: need 0 < near < far, got near={near}, far={far}")
    if not (math.isfinite(eps2d) and eps2d >= 0):
        raise RasterError(f"eps2d: must be finite and >= 0, got {eps2d}")
    if backend not in BACKENDS:
        raise RasterError(f"backend: expected one of {BACKENDS}, got {backend!r}")
    if background is None:
        return args._replace(background=torch.zeros(c, dtype=means.dtype, device=means.device))
    bg = _check_tensor("background", background, (c,))
    if bg.device != means.device:
        raise RasterError(f"background: on {bg.device}, but means is on {means.device}")
    return args._replace(background=bg.to(means.dtype))


def rasterize(
    means: Tensor,
    log_scales: Tensor,
    quats: Tensor,
    opacity_logits: Tensor,
    features: Tensor,
    camera: Camera,
    background: Tensor | None = None,
    near: float = 0.01,
    far: float = 1e10,
    eps2d: float = 0.3,
    backend: str = "auto",
    opacity_depth: bool = False,
) -> RasterOutput:
    """Render N Gaussians through ``camera``; differentiable w.r.t. every tensor input.

    Args:
        means: (N, 3) world-space centres.
        log_scales: (N, 3) log standard deviations along the Gaussian's own axes.
        quats: (N, 4) rotations as wxyz quaternions (normalized here).
        opacity_logits: (N,) opacities before the sigmoid.
        features: (N, C) per-Gaussian features blended into the image; C == 0 renders only
            depth and alpha (the cheap pass).
        camera: pose (world-to-camera, OpenCV axes) and intrinsics.
        background: (C,) blended in as ``(1 - alpha) * background``; None means zeros.
        near, far: view-space z range; Gaussians whose centre is outside it are culled.
        eps2d: low-pass dilation added to the 2D covariance diagonal (pixels^2).
        backend: "auto" (CUDA tensors -> gsplat, CPU tensors -> native kernel), "cpu", "cuda",
            or "reference" (dense float64, small scenes only).
        opacity_depth: also return ``opacity_depth``, the depth whose gradient reaches only
            the opacities (the soft-depth term on this render). The CPU kernel routes it in
            the same backward; the other backends render the depth a second time with the
            geometry detached (the same values, the same gradient).

    Returns:
        RasterOutput with image (C,H,W), depth (1,H,W) = sum of w_i z_i (not divided by alpha),
        alpha (1,H,W), radii (N,) int32 and means2d (N,2), whose ``.grad`` after backward is the
        screen-space gradient densification uses.
    """
    # The background may be None until _validate fills it in.
    args = RasterInputs(
        means, log_scales, quats, opacity_logits, features, camera, background,  # type: ignore[arg-type]
        near, far, eps2d,
    )  # fmt: skip
    args = _validate(args, backend)
    if backend == "auto":
        backend = "cuda" if means.is_cuda else "cpu"
    out = _dispatch(args, backend)
    if not opacity_depth or not torch.is_grad_enabled():
        out.opacity_depth = None
    elif out.opacity_depth is None:  # not the native CPU kernel's (it routes it itself)
        empty = features.new_zeros(means.shape[0], 0)
        geometry_detached = args._replace(
            means=means.detach(), log_scales=log_scales.detach(), quats=quats.detach(),
            features=empty, background=empty.new_zeros(0),
        )  # fmt: skip
        out.opacity_depth = _dispatch(geometry_detached, backend).depth
    return out


def _dispatch(args: RasterInputs, backend: str) -> RasterOutput:
    """Run the named backend on validated inputs."""
    means = args.means
    if backend == "reference":
        from sparsesplat.engine.raster.reference import rasterize_reference

        return rasterize_reference(args)
    if backend == "cuda":
        if not means.is_cuda:
            raise RasterError(f"backend='cuda': tensors must be on CUDA, got {means.device}")
        from sparsesplat.engine.raster.cuda_backend import rasterize_gsplat

        return rasterize_gsplat(args)
    if means.device.type != "cpu":
        raise RasterError(f"backend='cpu': tensors must be on the CPU, got {means.device}")
    if means.dtype != torch.float32:
        raise RasterError(
            f"means: the CPU kernel renders float32, got {means.dtype} (use backend='reference')"
        )
    from sparsesplat.engine.raster.cpu_backend import rasterize_cpu

    return rasterize_cpu(args)
