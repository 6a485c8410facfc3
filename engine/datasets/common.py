"""Helpers shared by the format loaders: building views, bounds and the initialization box."""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

import numpy as np
import torch

from sparsesplat.engine.camera import Camera
from sparsesplat.engine.camera_convert import project, undistort_image
from sparsesplat.engine.errors import SceneError
from sparsesplat.engine.images import read_mask, read_rgb, resize
from sparsesplat.engine.scene import View

Box = tuple[tuple[float, float, float], tuple[float, float, float]]


def load_view(
    name: str,
    image_path: Path,
    camera: Camera,
    background: Sequence[float],
    downscale: int = 1,
    mask_path: Path | None = None,
    depth: np.ndarray | None = None,
    depth_source: Path | None = None,
    distortion: tuple[float, ...] | None = None,
) -> View:
    """Read one image (composited on ``background``), check its size against the intrinsics,
    remove lens ``distortion`` (OpenCV k1, k2, p1, p2) if given, optionally shrink it by the
    integer ``downscale`` and attach a mask / user depth."""
    image = read_rgb(image_path, background=tuple(background))  # type: ignore[arg-type]
    h, w = image.shape[:2]
    if (w, h) != (camera.width, camera.height):
        raise SceneError(
            f"{image_path}: image is {w}x{h} but its camera intrinsics say "
            f"{camera.width}x{camera.height}"
        )
    if distortion is not None and any(distortion):
        image = undistort_image(image, camera.fx, camera.fy, camera.cx, camera.cy, distortion)
    mask = read_mask(mask_path) if mask_path is not None else None
    if mask is not None and mask.shape != (h, w):
        raise SceneError(f"{mask_path}: mask is {mask.shape[1]}x{mask.shape[0]}, image {w}x{h}")
    if depth is not None and depth.shape != (h, w):
        raise SceneError(
            f"{depth_source or name}: depth map is {depth.shape[1]}x{depth.shape[0]}, image {w}x{h}"
        )
    if downscale != 1:
        camera = camera.scaled(1.0 / downscale)
        size = (camera.width, camera.height)
        image = resize(image, size)
        if mask is not None:
            mask = resize(mask.astype(np.float32), size) >= 0.5
        if depth is not None:
            depth = resize(depth, size, nearest=True)
    return View(
        name=name,
        image=torch.from_numpy(np.ascontiguousarray(image)),
        camera=camera,
        mask=torch.from_numpy(mask) if mask is not None else None,
        depth=torch.from_numpy(depth.astype(np.float32)) if depth is not None else None,
    )


def check_downscale(downscale: int, source: str) -> int:
    """Validate the extra integer downscale factor."""
    if int(downscale) != downscale or downscale < 1:
        raise SceneError(f"{source}: downscale must be a positive integer, got {downscale!r}")
    return int(downscale)


def look_at_bounds(cameras: Sequence[Camera]) -> tuple[float, float]:
    """Near/far for formats without bounds: the point closest (least squares) to all optical
    axes is taken as the scene centre; near = 0.2x and far = 3x its nearest/farthest depth.
    Wide on purpose: priors sweep this range and must not clip the object."""
    a = np.zeros((3, 3))
    b = np.zeros(3)
    for cam in cameras:
        c2w = cam.camera_to_world.double().numpy()
        d, o = c2w[:3, 2], c2w[:3, 3]
        proj = np.eye(3) - np.outer(d, d)
        a += proj
        b += proj @ o
    centre = np.linalg.lstsq(a, b, rcond=None)[0]
    depths = []
    for cam in cameras:
        w2c = cam.world_to_camera.double().numpy()
        depths.append(float((w2c[:3, :3] @ centre + w2c[:3, 3])[2]))
    positive = [d for d in depths if d > 0]
    if not positive:  # cameras looking away from each other: fall back to baseline scale
        centres = np.stack([c.center.double().numpy() for c in cameras])
        span = float(np.linalg.norm(centres.max(0) - centres.min(0))) or 1.0
        return 0.05 * span, 50.0 * span
    return 0.2 * min(positive), 3.0 * max(positive)


def covisible_box(
    cameras: Sequence[Camera],
    near: Sequence[float],
    far: Sequence[float],
    samples: int = 4096,
    seed: int = 0,
) -> Box:
    """Box around the region seen by at least two of ``cameras`` between their near/far
    (inverse-depth sampling), from the 2nd-98th percentiles of such points per axis.

    This is the stand-in for DNGaussian's box from the COLMAP points (not shipped here)."""
    gen = torch.Generator().manual_seed(seed)
    kept = []
    allpts = []
    for i, cam in enumerate(cameras):
        u = torch.rand(samples, generator=gen, dtype=torch.float64) * cam.width
        v = torch.rand(samples, generator=gen, dtype=torch.float64) * cam.height
        inv = 1.0 / near[i] + torch.rand(samples, generator=gen, dtype=torch.float64) * (
            1.0 / far[i] - 1.0 / near[i]
        )
        z = 1.0 / inv
        xc = torch.stack([(u - cam.cx) / cam.fx * z, (v - cam.cy) / cam.fy * z, z], dim=-1)
        c2w = cam.camera_to_world.double()
        pts = xc @ c2w[:3, :3].T + c2w[:3, 3]
        seen = torch.zeros(samples, dtype=torch.int32)
        for other in cameras:
            uv, depth = project(other, pts)
            inside = (
                (depth > 0)
                & (uv[:, 0] >= 0)
                & (uv[:, 0] < other.width)
                & (uv[:, 1] >= 0)
                & (uv[:, 1] < other.height)
            )
            seen += inside.int()
        kept.append(pts[seen >= 2])
        allpts.append(pts)
    pts = torch.cat(kept)
    if pts.shape[0] < 100:
        pts = torch.cat(allpts)
    lo = torch.quantile(pts, 0.02, dim=0).tolist()
    hi = torch.quantile(pts, 0.98, dim=0).tolist()
    return ((lo[0], lo[1], lo[2]), (hi[0], hi[1], hi[2]))
