"""An analytic test scene: a textured plane seen by pinhole cameras, everything in float64.

Depth and images are exact functions of the pixel (ray-plane intersection, a smooth colour
pattern on the plane), so tests of back-projection and warping have a float64 ground truth.
"""

from __future__ import annotations

import math

import torch
from torch import Tensor

from sparsesplat.engine.camera import Camera


def look_at(eye: tuple[float, float, float], target: tuple[float, float, float]) -> Tensor:
    """World-to-camera (OpenCV axes, y down) float64 for a camera at ``eye`` facing ``target``."""
    e = torch.tensor(eye, dtype=torch.float64)
    z = torch.nn.functional.normalize(torch.tensor(target, dtype=torch.float64) - e, dim=0)
    up = torch.tensor([0.0, -1.0, 0.0], dtype=torch.float64)
    x = torch.nn.functional.normalize(torch.linalg.cross(up, z), dim=0)
    y = torch.linalg.cross(z, x)
    r = torch.stack([x, y, z])
    w2c = torch.eye(4, dtype=torch.float64)
    w2c[:3, :3] = r
    w2c[:3, 3] = -r @ e
    return w2c


def camera(
    eye: tuple[float, float, float],
    target: tuple[float, float, float] = (0.0, 0.0, 5.0),
    width: int = 48,
    height: int = 36,
    focal: float = 40.0,
) -> Camera:
    """A float64 pinhole camera at ``eye`` looking at ``target``."""
    return Camera(look_at(eye, target), focal, focal, width / 2, height / 2, width, height)


class Plane:
    """The plane ``normal . X = offset`` with a colour pattern of period ``period`` units."""

    def __init__(
        self,
        normal: tuple[float, float, float] = (0.15, -0.1, 1.0),
        offset: float = 5.0,
        period: float = 0.8,
    ) -> None:
        """Set up the plane; ``normal`` need not be unit length."""
        self.normal = torch.tensor(normal, dtype=torch.float64)
        self.offset = offset
        self.period = period

    def depth(self, cam: Camera) -> Tensor:
        """(H, W) float64 view-space z of the plane at each pixel centre (inf where the ray
        misses the plane or hits it behind the camera)."""
        w2c = cam.world_to_camera.double()
        rot, centre = w2c[:3, :3], -w2c[:3, :3].T @ w2c[:3, 3]
        v, u = torch.meshgrid(
            torch.arange(cam.height, dtype=torch.float64) + 0.5,
            torch.arange(cam.width, dtype=torch.float64) + 0.5,
            indexing="ij",
        )
        ray = torch.stack([(u - cam.cx) / cam.fx, (v - cam.cy) / cam.fy, torch.ones_like(u)], -1)
        denom = (ray @ rot) @ self.normal  # normal . (R^T ray)
        z = (self.offset - float(self.normal @ centre)) / denom
        return torch.where(torch.isfinite(z) & (z > 0), z, torch.full_like(z, math.inf))

    def colour(self, points: Tensor) -> Tensor:
        """(..., 3) colour in [0.1, 0.9] of world points on the plane."""
        k = 2 * math.pi / self.period
        x, y = points[..., 0], points[..., 1]
        return torch.stack(
            [
                0.5 + 0.4 * torch.sin(k * x) * torch.cos(0.7 * k * y),
                0.5 + 0.4 * torch.cos(0.8 * k * x + 0.3),
                0.5 + 0.4 * torch.sin(0.9 * k * y + 1.0),
            ],
            dim=-1,
        )

    def image(self, cam: Camera) -> Tensor:
        """(H, W, 3) float64 image of the plane (0 where the plane is not seen)."""
        z = self.depth(cam)
        w2c = cam.world_to_camera.double()
        v, u = torch.meshgrid(
            torch.arange(cam.height, dtype=torch.float64) + 0.5,
            torch.arange(cam.width, dtype=torch.float64) + 0.5,
            indexing="ij",
        )
        ray = torch.stack([(u - cam.cx) / cam.fx, (v - cam.cy) / cam.fy, torch.ones_like(u)], -1)
        zf = torch.where(torch.isfinite(z), z, torch.zeros_like(z))
        pts = (ray * zf[..., None] - w2c[:3, 3]) @ w2c[:3, :3]
        rgb = self.colour(pts)
        return torch.where(torch.isfinite(z)[..., None], rgb, torch.zeros_like(rgb))
