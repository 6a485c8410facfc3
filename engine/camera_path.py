"""Camera paths for novel-view renders: the LLFF forward-facing spiral of the reference.

What the reference code does (dngaussian-method.md §1.8, §1.9; read in
``scene_mix/dataset_readers.py`` ``CreateLLFFSpiral`` and ``utils/pose_utils.py``
``generate_spiral_path``): 180 cameras built from *every* pose of ``poses_bounds.npy`` (all
images, not just the training views). Poses are re-centred on their average pose (mean centre,
mean backward axis, mean up axis); the spiral radius per axis is the 90th percentile of the
re-centred |positions|; 2 turns, the depth axis oscillating at half rate (``zrate`` 0.5); every
camera looks at the point ``focal`` in front of the average pose,
``focal = 1 / (0.25 / (0.9 near) + 0.75 / (5 far))`` with near/far the smallest/largest bound of
all images. The LLFF loader keeps the path as ``Scene.render_path``; near-plane pruning
(``engine/train/regularizers/near_prune.py``) deletes Gaussians close to it.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np
import torch
from torch import Tensor

from sparsesplat.engine.camera import Camera
from sparsesplat.engine.camera_convert import cameras_from_llff
from sparsesplat.engine.errors import CameraError

_CV_TO_GL = torch.diag(torch.tensor([1.0, -1.0, -1.0], dtype=torch.float64))
"""Right-multiplying a rotation by this swaps OpenCV axes (right, down, forward) and the
reference's OpenGL-style (right, up, back) axes; it is its own inverse."""


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


def spiral_cameras(
    cameras_to_world: Sequence[Tensor] | Tensor,
    near: float,
    far: float,
    intrinsics: Camera,
    n_frames: int = 180,
) -> list[Camera]:
    """The spiral of :func:`spiral_path` as float32 cameras with the intrinsics (focal lengths,
    principal point, size) of ``intrinsics``, e.g. the first training view."""
    k = intrinsics
    return [
        Camera(torch.linalg.inv(pose).float(), k.fx, k.fy, k.cx, k.cy, k.width, k.height)
        for pose in spiral_path(cameras_to_world, near, far, n_frames)
    ]


def llff_render_path(
    poses_bounds: np.ndarray, image_size: tuple[int, int], n_frames: int = 180
) -> list[Camera]:
    """The reference's 180 spiral cameras for an LLFF scene from its ``poses_bounds.npy`` rows
    (all images) and the (height, width) of the images trained on; intrinsics of the first
    image."""
    cams, bounds = cameras_from_llff(poses_bounds, image_size, "poses_bounds.npy")
    c2w = [c.camera_to_world.double() for c in cams]
    near, far = float(bounds[:, 0].min()), float(bounds[:, 1].max())
    return spiral_cameras(c2w, near, far, cams[0], n_frames)
