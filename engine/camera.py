"""The one internal camera convention.

A camera is world-to-camera (4x4, rigid) in OpenCV axes: +x right, +y down, +z forward (the
camera looks down +z). Intrinsics are the pinhole fx, fy, cx, cy in pixels, where the centre of
pixel (u, v) sits at (u + 0.5, v + 0.5). Depth everywhere in sparsesplat is view-space z.
Converters from other conventions live in ``engine.camera_convert``.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING

import torch
from torch import Tensor

if TYPE_CHECKING:
    from sparsesplat.api.cameras import PinholeCamera


@dataclass(frozen=True)
class Camera:
    """A pinhole camera: world-to-camera pose in OpenCV axes plus intrinsics in pixels."""

    world_to_camera: Tensor
    """(4, 4) rigid transform taking world points to camera coordinates (OpenCV axes)."""
    fx: float
    """Focal length along x, in pixels."""
    fy: float
    """Focal length along y, in pixels."""
    cx: float
    """Principal point x, in pixels (pixel centres are at +0.5)."""
    cy: float
    """Principal point y, in pixels."""
    width: int
    """Image width in pixels."""
    height: int
    """Image height in pixels."""

    @property
    def K(self) -> Tensor:  # noqa: N802 - the conventional name of the intrinsic matrix
        """The 3x3 intrinsic matrix, same dtype/device as the pose."""
        w2c = self.world_to_camera
        k = torch.zeros(3, 3, dtype=w2c.dtype, device=w2c.device)
        k[0, 0], k[1, 1], k[0, 2], k[1, 2], k[2, 2] = self.fx, self.fy, self.cx, self.cy, 1.0
        return k

    @property
    def camera_to_world(self) -> Tensor:
        """(4, 4) inverse of the pose, computed rigidly (R^T, -R^T t)."""
        w2c = self.world_to_camera
        r, t = w2c[:3, :3], w2c[:3, 3]
        c2w = torch.eye(4, dtype=w2c.dtype, device=w2c.device)
        c2w[:3, :3] = r.T
        c2w[:3, 3] = -r.T @ t
        return c2w

    @property
    def center(self) -> Tensor:
        """(3,) camera centre in world coordinates."""
        return self.camera_to_world[:3, 3]

    def to(self, device: torch.device | str, dtype: torch.dtype | None = None) -> Camera:
        """Return the same camera with its pose on ``device`` (and ``dtype`` if given)."""
        pose = self.world_to_camera.to(device=device, dtype=dtype or self.world_to_camera.dtype)
        return Camera(pose, self.fx, self.fy, self.cx, self.cy, self.width, self.height)

    @classmethod
    def from_wire(cls, camera: PinholeCamera, downscale: int = 1) -> Camera:
        """The engine camera of a wire camera (any convention and pose direction, converted to
        world-to-camera OpenCV), for an image shrunk by the integer ``downscale``."""
        w2c = torch.tensor(camera.world_to_camera_opencv(), dtype=torch.float64).float()
        s = float(downscale)
        return cls(
            w2c, camera.fx / s, camera.fy / s, camera.cx / s, camera.cy / s,
            max(1, camera.width // downscale), max(1, camera.height // downscale),
        )  # fmt: skip

    def scaled(self, factor: float) -> Camera:
        """Return the camera for an image resized by ``factor`` (intrinsics scale, pose kept)."""
        return Camera(
            self.world_to_camera,
            self.fx * factor,
            self.fy * factor,
            self.cx * factor,
            self.cy * factor,
            max(1, round(self.width * factor)),
            max(1, round(self.height * factor)),
        )


def pixel_rays(
    camera: Camera, dtype: torch.dtype = torch.float64, device: torch.device | str = "cpu"
) -> Tensor:
    """(H, W, 3) camera-space rays with z = 1 through the pixel centres of ``camera``: a pixel's
    view-space point at depth z is ``z * ray``."""
    v, u = torch.meshgrid(
        torch.arange(camera.height, dtype=dtype, device=device) + 0.5,
        torch.arange(camera.width, dtype=dtype, device=device) + 0.5,
        indexing="ij",
    )
    return torch.stack(
        [(u - camera.cx) / camera.fx, (v - camera.cy) / camera.fy, torch.ones_like(u)], dim=-1
    )
