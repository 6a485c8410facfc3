"""A textured synthetic scene rendered at known poses: photos for camera estimation that
need no shared data.

Three textured rectangles (a floor, a back wall, a side wall: not one plane, so relative pose
is well defined) carry random coloured discs at several sizes (SIFT finds blobs and corners).
Pixels are ray-cast exactly (no rasterizer), so the ground-truth poses are exact.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from PIL import Image, ImageDraw

WIDTH, HEIGHT = 320, 240
"""Photo size."""
FOCAL = 0.9 * WIDTH
"""Focal length in pixels (principal point at the centre)."""


@dataclass
class Plane:
    """A textured rectangle: origin corner, two edge vectors, a texture image."""

    origin: np.ndarray
    u: np.ndarray
    v: np.ndarray
    texture: np.ndarray


def _texture(rng: np.random.Generator, size: int = 512) -> np.ndarray:
    image = Image.new("RGB", (size, size), tuple(int(c) for c in rng.integers(60, 200, 3)))
    draw = ImageDraw.Draw(image)
    for radius, count in ((40, 30), (18, 120), (8, 400)):
        for _ in range(count):
            x, y = rng.uniform(0, size, 2)
            r = radius * rng.uniform(0.5, 1.0)
            colour = tuple(int(c) for c in rng.integers(0, 256, 3))
            draw.ellipse((x - r, y - r, x + r, y + r), fill=colour)
    return np.asarray(image, dtype=np.float32) / 255.0


def make_planes(seed: int) -> list[Plane]:
    """Floor, back wall and side wall of a small room corner, textured from ``seed``."""
    rng = np.random.default_rng(seed)
    a = np.array
    return [
        Plane(a([-2.0, 1.0, 0.5]), a([4.0, 0.0, 0.0]), a([0.0, 0.0, 3.5]), _texture(rng)),
        Plane(a([-2.0, -2.0, 4.0]), a([4.0, 0.0, 0.0]), a([0.0, 3.0, 0.0]), _texture(rng)),
        Plane(a([-2.0, -2.0, 0.5]), a([0.0, 0.0, 3.5]), a([0.0, 3.0, 0.0]), _texture(rng)),
    ]


def look_at(eye: np.ndarray, target: np.ndarray) -> np.ndarray:
    """World-to-camera (OpenCV axes, y down) for a camera at ``eye`` looking at ``target``."""
    z = (target - eye) / np.linalg.norm(target - eye)
    x = np.cross(np.array([0.0, -1.0, 0.0]), z)
    x /= np.linalg.norm(x)
    y = np.cross(z, x)
    w2c = np.eye(4)
    w2c[:3, :3] = np.stack([x, y, z])
    w2c[:3, 3] = -w2c[:3, :3] @ eye
    return w2c


def camera_poses(n: int, spread: float = 0.5) -> list[np.ndarray]:
    """``n`` cameras on a sideways arc (x from -spread to +spread) looking into the corner."""
    poses = []
    for k in range(n):
        s = -spread + 2 * spread * k / max(n - 1, 1)
        eye = np.array([s, -0.2 + 0.1 * math.sin(3 * s), -0.5])
        poses.append(look_at(eye, np.array([0.2 * s, 0.0, 3.0])))
    return poses


def render(planes: list[Plane], w2c: np.ndarray) -> np.ndarray:
    """(H, W, 3) uint8 photo of ``planes`` from ``w2c`` (nearest hit per pixel, grey sky)."""
    r, t = w2c[:3, :3], w2c[:3, 3]
    eye = -r.T @ t
    v, u = np.meshgrid(np.arange(HEIGHT) + 0.5, np.arange(WIDTH) + 0.5, indexing="ij")
    rays = np.stack([(u - WIDTH / 2) / FOCAL, (v - HEIGHT / 2) / FOCAL, np.ones_like(u)], -1)
    rays = rays @ r  # camera -> world directions (R^T d, row vectors)
    best = np.full((HEIGHT, WIDTH), np.inf)
    out = np.full((HEIGHT, WIDTH, 3), 0.5, dtype=np.float32)
    for plane in planes:
        normal = np.cross(plane.u, plane.v)
        denom = rays @ normal
        with np.errstate(divide="ignore", invalid="ignore"):
            depth = ((plane.origin - eye) @ normal) / denom
        hit = eye + depth[..., None] * rays - plane.origin
        a = hit @ plane.u / (plane.u @ plane.u)
        b = hit @ plane.v / (plane.v @ plane.v)
        ok = (depth > 0) & (depth < best) & (a >= 0) & (a < 1) & (b >= 0) & (b < 1)
        size = plane.texture.shape[0]
        ti = np.clip((b * size).astype(int), 0, size - 1)
        tj = np.clip((a * size).astype(int), 0, size - 1)
        out[ok] = plane.texture[ti[ok], tj[ok]]
        best[ok] = depth[ok]
    return (out * 255 + 0.5).astype(np.uint8)


def write_photos(
    folder: Path, poses: list[np.ndarray], seed: int = 0, prefix: str = "photo"
) -> list[Path]:
    """Render ``poses`` of the scene ``seed`` into ``folder`` as PNGs; their paths."""
    folder.mkdir(parents=True, exist_ok=True)
    planes = make_planes(seed)
    paths = []
    for i, pose in enumerate(poses):
        paths.append(folder / f"{prefix}_{i}.png")
        Image.fromarray(render(planes, pose)).save(paths[-1])
    return paths
