"""LLFF near-plane pruning against the spiral render path and at evaluation.

What the reference code does (dngaussian-method.md §1.8, §1.9 "Near/far", §6 item 4; read in
``train_llff.py``, ``scene_mix/dataset_readers.py`` ``CreateLLFFSpiral``, ``utils/pose_utils.py``
``generate_spiral_path`` and ``render.py``; not in the paper):

- **Path**: 180 cameras on the LLFF forward-facing spiral built from *every* pose of
  ``poses_bounds.npy`` (all images, not just the 3 training views): poses are re-centred on
  their average pose (mean centre, mean backward axis, mean up axis); the spiral radius per
  axis is the 90th percentile of the re-centred |positions|; 2 turns, the depth axis
  oscillating at half rate (``zrate`` 0.5); every camera looks at the point ``focal`` in front
  of the average pose, ``focal = 1 / (0.25 / (0.9 near) + 0.75 / (5 far))`` with near/far the
  smallest/largest bound of all images. :func:`spiral_path`, :func:`llff_render_path`.
- **Training**: when ``(iteration - 1) % 25 == 0`` and ``iteration > 2000``
  (:meth:`NearPruneSchedule.due`), every Gaussian whose centre is within Euclidean distance
  ``near`` (``--near 10``, absolute dataset units) of *any* of the 180 path cameras is deleted
  (:func:`near_prune_mask`; the strategy prunes those rows with their optimizer state). It
  runs after densification, before the photometric Adam step.
- **Evaluation**: before rendering the held-out views, Gaussians within ``near`` of any of the
  cameras being rendered are removed (test poses only, no test pixels). Call
  :func:`near_prune_mask` with the held-out cameras' centres and render the kept rows.

The criterion is a sphere around each camera centre, not a plane: "near-plane" is the
reference's name. ``mode="depth"`` offers the planar variant (view-space z in (0, near) for
some camera), which also removes Gaussians far off to the side of a camera's axis.

Units: the reference's 10 is absolute in the COLMAP units of the 8 LLFF scenes. This
project's LLFF loader keeps COLMAP units too, but the shared scenes have near bounds of 1.25
(juicebox_table) and 3.12 (beer_can), where 10 would delete most of the scene: the radius must
be set per scene (relative to ``Scene.near``) and measured.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Literal

import numpy as np
import torch
from torch import Tensor

from sparsesplat.engine.camera import Camera
from sparsesplat.engine.camera_convert import cameras_from_llff
from sparsesplat.engine.errors import CameraError

_CV_TO_GL = torch.diag(torch.tensor([1.0, -1.0, -1.0], dtype=torch.float64))
"""Right-multiplying a rotation by this swaps OpenCV axes (right, down, forward) and the
reference's OpenGL-style (right, up, back) axes; it is its own inverse."""


@dataclass(frozen=True)
class NearPruneSchedule:
    """When the training-time prune runs (the reference: every 25 iterations after 2000)."""

    every: int = 25
    """Prune on iterations with ``(iteration - 1) % every == 0``."""
    after: int = 2000
    """... and ``iteration > after``."""

    def due(self, iteration: int) -> bool:
        """True when 1-based ``iteration`` prunes."""
        if self.every < 1:
            raise CameraError(f"near prune: every must be >= 1, got {self.every}")
        return iteration > self.after and (iteration - 1) % self.every == 0


def _normalize(v: Tensor) -> Tensor:
    n = v.norm()
    if not bool(n > 0):
        raise CameraError("spiral path: degenerate camera axes (they cancel on average)")
    return v / n


def _view_matrix(back: Tensor, up: Tensor, position: Tensor) -> Tensor:
    """(3, 4) [right | up | back | position] (OpenGL-style axes) from a backward axis and an
    approximate up axis, as the reference's ``viewmatrix``."""
    z = _normalize(back)
    x = _normalize(torch.linalg.cross(up, z))
    y = _normalize(torch.linalg.cross(z, x))
    return torch.stack([x, y, z, position], dim=1)


def _average_pose(poses: Tensor) -> Tensor:
    """(3, 4) mean centre, mean backward axis, mean up axis of (N, 3, 4) OpenGL-style poses."""
    return _view_matrix(poses[:, :, 2].mean(0), poses[:, :, 1].mean(0), poses[:, :, 3].mean(0))


def _pad(pose: Tensor) -> Tensor:
    out = torch.eye(4, dtype=pose.dtype).expand(*pose.shape[:-2], 4, 4).clone()
    out[..., :3, :4] = pose
    return out


def spiral_path(
    cameras_to_world: Sequence[Tensor] | Tensor,
    near: float,
    far: float,
    n_frames: int = 180,
    n_rots: int = 2,
    zrate: float = 0.5,
    percentile: float = 90.0,
) -> Tensor:
    """(n_frames, 4, 4) float64 camera-to-world poses (OpenCV axes) of the LLFF spiral.

    ``cameras_to_world``: (N, 4, 4) or a list of (4, 4) OpenCV camera-to-world poses of every
    image; ``near``/``far``: the smallest near and the largest far bound of all images."""
    if isinstance(cameras_to_world, Tensor):
        c2w = cameras_to_world.detach().cpu().double()
    elif len(cameras_to_world) == 0:
        raise CameraError("spiral path: no camera poses")
    else:
        c2w = torch.stack([p.detach().cpu().double() for p in cameras_to_world])
    if c2w.dim() != 3 or c2w.shape[1:] != (4, 4) or c2w.shape[0] < 1:
        raise CameraError(f"spiral path: expected (N, 4, 4) poses, got {tuple(c2w.shape)}")
    if not bool(torch.isfinite(c2w).all()):
        raise CameraError("spiral path: poses contain non-finite values")
    if not (math.isfinite(near) and math.isfinite(far) and 0 < near <= far):
        raise CameraError(f"spiral path: need 0 < near <= far, got {near}, {far}")
    if n_frames < 1:
        raise CameraError(f"spiral path: n_frames must be >= 1, got {n_frames}")
    gl = c2w[:, :3, :4].clone()
    gl[:, :, :3] = gl[:, :, :3] @ _CV_TO_GL
    avg = _pad(_average_pose(gl))
    centred = (torch.linalg.inv(avg) @ _pad(gl))[:, :3, :4]
    radii = torch.quantile(centred[:, :, 3].abs(), percentile / 100.0, dim=0)  # linear, as numpy
    dt = 0.75
    focal = 1.0 / ((1.0 - dt) / (0.9 * near) + dt / (5.0 * far))
    frame = _average_pose(centred)
    up = centred[:, :, 1].mean(0)
    lookat = frame @ torch.tensor([0.0, 0.0, -focal, 1.0], dtype=torch.float64)
    # np.linspace(0, 2 pi n_rots, n_frames, endpoint=False), as the reference.
    thetas = torch.arange(n_frames, dtype=torch.float64) * (2.0 * math.pi * n_rots / n_frames)
    scale = torch.cat([radii, torch.ones(1, dtype=torch.float64)])
    poses = []
    for theta in thetas:
        t = torch.stack([theta.cos(), -theta.sin(), -(theta * zrate).sin(), torch.ones(())])
        position = frame @ (scale * t.double())
        poses.append(_view_matrix(position - lookat, up, position))
    path = avg @ _pad(torch.stack(poses))
    path[:, :3, :3] = path[:, :3, :3] @ _CV_TO_GL
    return path


def llff_render_path(
    poses_bounds: np.ndarray, image_size: tuple[int, int], n_frames: int = 180
) -> list[Camera]:
    """The reference's 180 spiral cameras for an LLFF scene from its ``poses_bounds.npy`` rows
    (all images) and the (height, width) of the images trained on; intrinsics of the first
    image. Poses in float32 like the training cameras."""
    cams, bounds = cameras_from_llff(poses_bounds, image_size, "poses_bounds.npy")
    c2w = [c.camera_to_world.double() for c in cams]
    path = spiral_path(c2w, float(bounds[:, 0].min()), float(bounds[:, 1].max()), n_frames)
    ref = cams[0]
    out = []
    for pose in path:
        w2c = torch.linalg.inv(pose)
        out.append(Camera(w2c.float(), ref.fx, ref.fy, ref.cx, ref.cy, ref.width, ref.height))
    return out


def near_prune_mask(
    means: Tensor,
    cameras: Sequence[Camera] | Tensor,
    near: float,
    mode: Literal["distance", "depth"] = "distance",
    chunk: int = 65536,
) -> Tensor:
    """(N,) bool: the Gaussians to prune, those closer than ``near`` to any camera.

    ``cameras``: Camera objects, or for ``mode="distance"`` an (M, 3) tensor of centres.
    ``"distance"`` (the reference): Euclidean distance from the centre ``< near``.
    ``"depth"``: view-space z in ``(0, near)`` for some camera (in front of it, before its
    near plane). Distances are computed in float64, so the decision is exact for float32
    means up to float64 rounding. No camera or no Gaussian: nothing to prune."""
    if not (math.isfinite(near) and near >= 0):
        raise CameraError(f"near prune: near must be finite and >= 0, got {near}")
    n = means.shape[0]
    out = torch.zeros(n, dtype=torch.bool, device=means.device)
    if n == 0 or len(cameras) == 0 or near == 0:
        return out
    pts = means.detach().cpu().double()
    if mode == "distance":
        if isinstance(cameras, Tensor):
            centres = cameras.detach().cpu().double().reshape(-1, 3)
        else:
            centres = torch.stack([c.center.detach().cpu().double() for c in cameras])
        for s in range(0, n, chunk):
            # Direct differences, not the |a|^2 + |b|^2 - 2ab shortcut that cancels.
            d = torch.cdist(
                pts[s : s + chunk], centres, compute_mode="donot_use_mm_for_euclid_dist"
            )
            out[s : s + chunk] = (d < near).any(dim=1).to(out.device)
        return out
    if mode != "depth":
        raise CameraError(f"near prune: mode must be 'distance' or 'depth', got {mode!r}")
    if isinstance(cameras, Tensor):
        raise CameraError("near prune: mode 'depth' needs Camera objects (poses), not centres")
    rows = torch.stack([c.world_to_camera.detach().cpu().double()[2] for c in cameras])
    for s in range(0, n, chunk):
        z = pts[s : s + chunk] @ rows[:, :3].T + rows[:, 3]
        out[s : s + chunk] = ((z > 0) & (z < near)).any(dim=1).to(out.device)
    return out
