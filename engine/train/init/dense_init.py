"""Dense initialisation from the training views themselves: back-projected confident depth.

Instead of a random box (dngaussian-method.md §1.2), the initial Gaussians are the pixels of
the training views whose metric depth is trusted, lifted to 3D with their colours. The depth
comes from the plane-sweep prior (``engine.priors.plane_sweep``: metric view-space z plus a
confidence in [0, 1] that already folds in ZNCC peakedness, texture and a cross-view geometric
check), or from any metric depth with :func:`photo_consistency` as the confidence. The method
document reports +0.8 dB on LLFF for DNGaussian with FSGS's 3-view MVS point cloud (§1.2,
§4.1); its MVS variant also changes hyper-parameters (§1.9: centre LR 0.0005 -> 0.000005 x
extent, λ_dssim 0.25, grad threshold 0.0008, tolerance 0.01, scaling LR 0.005, no scale
penalty), which the preset that enables this init should adopt.

Where it runs: once, at model set-up (today ``Trainer._setup_model``, where
``points = lo + rand * (hi - lo)`` draws the random box), after the priors are prepared::

    points, colours, cut = dense_points_from_priors(
        [v.image for v in scene.train], [v.camera for v in scene.train], priors,
        target=cfg.init.dense_points, generator=trainer_generator,
        min_confidence=cfg.init.dense_min_confidence, min_points=cfg.init.dense_min_points)

The points then feed ``NeuralColor.create`` (hash-grid bounds) and ``Gaussians.from_points``
(k-NN scales) exactly as the random points do; the colours can seed SH DC terms. When no pixel
is confident, :class:`PriorError` is raised and the caller falls back to the random box.

Conventions (``engine.camera``): OpenCV axes, depth = view-space z, pixel (u, v) has its
centre at (u + 0.5, v + 0.5). Images are (H, W, 3) as in ``View.image``.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from pathlib import Path
from typing import Any, NamedTuple

import torch
import torch.nn.functional as F
from torch import Tensor

from sparsesplat.engine.camera import Camera, pixel_rays
from sparsesplat.engine.errors import PriorError
from sparsesplat.engine.priors.base import PriorDepth
from sparsesplat.engine.scene import Scene


def init_priors(
    scene: Scene, given: Sequence[Any] | None, cache_dir: Path | None
) -> list[PriorDepth]:
    """The metric depth the dense init back-projects: ``given`` when every one is a metric
    :class:`PriorDepth` (a run on the plane-sweep prior), else a plane-sweep prior computed
    from ``scene`` (read from / written to ``cache_dir`` when given). The regularisation prior
    of a run is often monocular (pydnet), whose depth is not in scene units."""
    if given and all(isinstance(p, PriorDepth) and p.metric for p in given):
        return list(given)
    from sparsesplat.engine.priors import compute_priors

    return compute_priors(scene, "plane_sweep", cache_dir=cache_dir)


def backproject(depth: Tensor, camera: Camera) -> Tensor:
    """(H, W, 3) world points of every pixel of ``depth`` (H, W), view-space z, in float64.

    ``X = R^T (z * ray - t)`` for the world-to-camera ``[R | t]``. No validity check: the
    caller masks pixels whose depth is not finite and positive."""
    _check_map("depth", depth, camera)
    w2c = camera.world_to_camera.detach().cpu().double()
    rot, trans = w2c[:3, :3], w2c[:3, 3]
    cam_pts = pixel_rays(camera) * depth.detach().cpu().double()[..., None]
    return (cam_pts - trans) @ rot


def _check_map(name: str, value: Tensor, camera: Camera) -> None:
    if tuple(value.shape[:2]) != (camera.height, camera.width):
        raise PriorError(
            f"dense init: {name} has shape {tuple(value.shape)}, the camera is "
            f"{camera.height}x{camera.width}"
        )


def _project(points: Tensor, camera: Camera) -> tuple[Tensor, Tensor, Tensor]:
    """World points (P, 3) float64 -> pixel coordinates u, v (continuous) and view z."""
    w2c = camera.world_to_camera.detach().cpu().double()
    q = points @ w2c[:3, :3].T + w2c[:3, 3]
    z = q[:, 2]
    safe = torch.where(z > 0, z, torch.ones_like(z))
    return camera.fx * q[:, 0] / safe + camera.cx, camera.fy * q[:, 1] / safe + camera.cy, z


def _sample(image_chw: Tensor, u: Tensor, v: Tensor, camera: Camera, mode: str) -> Tensor:
    """Bilinear/nearest samples (C, P) of a (C, H, W) map at continuous pixel coordinates."""
    grid = torch.stack([u / camera.width * 2 - 1, v / camera.height * 2 - 1], dim=-1)
    out = F.grid_sample(
        image_chw[None], grid.view(1, 1, -1, 2), mode=mode, align_corners=False
    )  # (1, C, 1, P)
    return out[0, :, 0]


def photo_consistency(
    images: Sequence[Tensor],
    cameras: Sequence[Camera],
    depths: Sequence[Tensor],
    color_tolerance: float = 0.1,
    depth_tolerance: float = 0.05,
    window: int = 5,
) -> list[Tensor]:
    """Per view, an (H, W) float32 map: 1 where the pixel's depth is confirmed by another view.

    Every pixel of view i is lifted to 3D with its depth and projected into each other view j.
    View j confirms pixel p when p's point lies in front of j and inside its frame, j's own
    depth there agrees to within ``depth_tolerance`` relative (so a point j sees occluded does
    not pass on a chance colour match), and the colour difference between i and j, averaged
    over RGB and over the ``window`` x ``window`` pixels around p (each warped with its own
    depth; invalid neighbours count as a difference of 1), is at most ``color_tolerance``. A
    single pixel's colour matches by chance on periodic texture; a window rarely does. Pixels
    with non-finite or non-positive depth get 0.
    """
    if window < 1 or window % 2 == 0:
        raise PriorError(f"photo_consistency: window must be odd and >= 1, got {window}")
    if not (len(images) == len(cameras) == len(depths)):
        raise PriorError(
            f"photo_consistency: {len(images)} images, {len(cameras)} cameras, {len(depths)} depths"
        )
    chw = [img.detach().cpu().double().permute(2, 0, 1) for img in images]
    dmaps = [d.detach().cpu().double() for d in depths]
    out = []
    for i, cam in enumerate(cameras):
        _check_map("image", images[i], cam)
        _check_map("depth", dmaps[i], cam)
        d = dmaps[i]
        valid = (torch.isfinite(d) & (d > 0)).reshape(-1)
        pts = backproject(torch.where(valid.view_as(d), d, torch.ones_like(d)), cam).reshape(-1, 3)
        colour = chw[i].reshape(3, -1)
        ok = torch.zeros_like(valid)
        for j, other in enumerate(cameras):
            if j == i:
                continue
            _check_map("depth", dmaps[j], other)
            u, v, z = _project(pts, other)
            inside = (z > 0) & (u >= 0) & (u <= other.width) & (v >= 0) & (v <= other.height)
            seen = _sample(chw[j], u, v, other, "bilinear")
            diff = (seen - colour).abs().mean(dim=0)
            diff = torch.where(inside & valid, diff, torch.ones_like(diff))
            # Window mean of the per-pixel difference = the window's SAD / its pixel count.
            sad = F.avg_pool2d(
                diff.view(1, 1, cam.height, cam.width),
                window,
                stride=1,
                padding=window // 2,
                count_include_pad=False,
            ).reshape(-1)
            dj = _sample(dmaps[j][None], u, v, other, "nearest")[0]
            geo = torch.isfinite(dj) & ((dj - z).abs() <= depth_tolerance * z.abs())
            ok |= inside & geo & (sad <= color_tolerance)
        out.append((ok & valid).view(cam.height, cam.width).float())
    return out


class DensePoints(NamedTuple):
    """The dense init's draw: points, their colours and the confidence cut that was used."""

    points: Tensor
    """(N, 3) float32 back-projected centres, on the CPU."""
    colours: Tensor
    """(N, 3) float32 colours in [0, 1] of the pixels they came from."""
    cut: float
    """Smallest confidence a drawn pixel could have: ``min_confidence``, or lower where the
    floor (``min_points``) had to reach past it."""

    def describe(self, min_confidence: float) -> str:
        """One line for a run's metrics, e.g. ``dense: 8000 points`` or, when the floor
        lowered the cut, ``dense: 2000 points (cut lowered 0.7 -> 0.412 to reach the floor)``."""
        text = f"dense: {len(self.points)} points"
        if self.cut < min_confidence:
            text += f" (cut lowered {min_confidence:g} -> {self.cut:.3g} to reach the floor)"
        return text


def dense_points(
    images: Sequence[Tensor],
    cameras: Sequence[Camera],
    depths: Sequence[Tensor],
    confidences: Sequence[Tensor],
    target: int,
    generator: torch.Generator,
    min_confidence: float = 0.5,
    min_points: int = 0,
) -> DensePoints:
    """Back-project the pixels with ``confidence >= min_confidence`` (and finite, positive
    depth) of every view, pool them and draw ``target`` of them uniformly without replacement
    (all of them when fewer). Returns float32 CPU points and colours and the cut used.

    ``min_points``: a floor. When fewer than ``min(min_points, target)`` pixels pass the cut
    (a low-texture capture, where the plane sweep is sure of little), the most confident
    pixels are taken instead, that many, so the start is not a handful of points; pixels of
    zero confidence never count.

    Raises :class:`PriorError` when no pixel qualifies (the caller falls back to the random
    box) or when the inputs disagree in count or size."""
    if target < 1:
        raise PriorError(f"dense init: target point count must be >= 1, got {target}")
    if min_points < 0:
        raise PriorError(f"dense init: min_points must be >= 0, got {min_points}")
    if not math.isfinite(min_confidence):
        raise PriorError(f"dense init: min_confidence must be finite, got {min_confidence}")
    if not (len(images) == len(cameras) == len(depths) == len(confidences)):
        raise PriorError(
            f"dense init: {len(images)} images, {len(cameras)} cameras, {len(depths)} depths, "
            f"{len(confidences)} confidences"
        )
    floor = min(min_points, target)
    all_pts, all_rgb, all_conf = [], [], []
    for img, cam, d, c in zip(images, cameras, depths, confidences, strict=True):
        _check_map("image", img, cam)
        _check_map("depth", d, cam)
        _check_map("confidence", c, cam)
        d64 = d.detach().cpu().double()
        conf = c.detach().cpu().float()
        usable = torch.isfinite(d64) & (d64 > 0)
        # Pixels the floor may reach are pooled too, so a view whose confident pixels are
        # few still lends its best ones.
        passes = conf >= min_confidence
        keep = usable & (passes | (conf > 0)) if floor else usable & passes
        if not bool(keep.any()):
            continue
        pts = backproject(torch.where(keep, d64, torch.zeros_like(d64)), cam)
        all_pts.append(pts[keep])
        all_rgb.append(img.detach().cpu().double()[keep])
        all_conf.append(conf[keep])
    if not all_pts:
        raise PriorError(
            f"dense init: no pixel has finite positive depth and confidence >= {min_confidence}"
        )
    pts64, rgb64, conf = torch.cat(all_pts), torch.cat(all_rgb), torch.cat(all_conf)
    passed = conf >= min_confidence
    cut = float(min_confidence)
    if int(passed.sum()) < floor:
        # The floor's most confident pixels; a stable sort keeps ties in pixel order, so the
        # pick does not depend on the sort's implementation.
        pick = torch.argsort(conf, descending=True, stable=True)[:floor]
        cut = min(cut, float(conf[pick[-1]]))
        pts64, rgb64 = pts64[pick], rgb64[pick]
    else:
        pts64, rgb64 = pts64[passed], rgb64[passed]
    if pts64.shape[0] > target:
        pick = torch.randperm(pts64.shape[0], generator=generator)[:target]
        pts64, rgb64 = pts64[pick], rgb64[pick]
    return DensePoints(pts64.float(), rgb64.clamp(0, 1).float(), cut)


def dense_points_from_priors(
    images: Sequence[Tensor],
    cameras: Sequence[Camera],
    priors: Sequence[PriorDepth],
    target: int,
    generator: torch.Generator,
    min_confidence: float = 0.5,
    color_tolerance: float = 0.1,
    depth_tolerance: float = 0.05,
    min_points: int = 0,
) -> DensePoints:
    """:func:`dense_points` on metric priors. A prior whose confidence is all zero or all one
    carries no information (a user depth map, say); :func:`photo_consistency` replaces it.
    Monocular (non-metric) priors are refused with :class:`PriorError`: their depth is not in
    scene units and cannot be back-projected."""
    for i, p in enumerate(priors):
        if not p.metric:
            raise PriorError(
                f"dense init: prior {i} ({p.kind or 'unknown'}) is not metric; back-projection "
                "needs view-space z in scene units (use the plane-sweep prior)"
            )
    depths = [p.depth for p in priors]
    confs: list[Tensor] = []
    checked: list[Tensor] | None = None
    for i, p in enumerate(priors):
        c = p.confidence
        flat = c.numel() == 0 or bool((c == c.reshape(-1)[0]).all())
        if flat:
            if checked is None:
                checked = photo_consistency(
                    images, cameras, depths, color_tolerance, depth_tolerance
                )
            c = checked[i]
        confs.append(c)
    return dense_points(
        images, cameras, depths, confs, target, generator, min_confidence, min_points
    )
