"""A ray-cast synthetic scene with known depth: textured planes seen by posed cameras."""

from __future__ import annotations

import numpy as np
import torch

from sparsesplat.engine.camera import Camera
from sparsesplat.engine.scene import Scene, View
from tests.engine.datasets.synthetic import look_at_c2w


def texture(x: np.ndarray, y: np.ndarray, seed: int) -> np.ndarray:
    """Smooth random RGB texture on world (x, y): a sum of random sinusoids."""
    rng = np.random.default_rng(seed)
    out = np.zeros((*x.shape, 3))
    for c in range(3):
        for _ in range(12):
            fx, fy = rng.normal(scale=12.0, size=2)
            out[..., c] += np.sin(fx * x + fy * y + rng.uniform(0, 6.3))
    return np.clip(0.5 + out / 8.0, 0, 1)


def plane_scene(
    seed: int = 0, views: int = 3, size: tuple[int, int] = (96, 72), step: bool = True
) -> tuple[Scene, list[np.ndarray]]:
    """Cameras on an arc looking at the world plane z = 0 from about 3 units; with ``step``,
    a raised square (z = -0.5, towards the cameras) in the middle. Returns the scene and the
    true view-space depth of every training view."""
    w, h = size
    views_out, depths = [], []
    for i in range(views):
        angle = -0.25 + 0.5 * i / max(1, views - 1)
        eye = np.array([3.0 * np.sin(angle), 0.2 * i, -3.0 * np.cos(angle)])
        c2w = look_at_c2w(eye, np.zeros(3))
        cam = Camera(torch.from_numpy(np.linalg.inv(c2w)).float(), 80.0, 80.0, w / 2, h / 2, w, h)
        v, u = np.mgrid[0:h, 0:w] + 0.5
        dirs_cam = np.stack([(u - w / 2) / 80.0, (v - h / 2) / 80.0, np.ones_like(u)], -1)
        dirs = dirs_cam @ c2w[:3, :3].T
        t = (0.0 - eye[2]) / dirs[..., 2]  # ray parameter = view depth (dirs_cam has z = 1)
        hit = eye + dirs * t[..., None]
        if step:
            t2 = (-0.5 - eye[2]) / dirs[..., 2]
            hit2 = eye + dirs * t2[..., None]
            on_box = (np.abs(hit2[..., 0]) < 0.4) & (np.abs(hit2[..., 1]) < 0.4)
            t = np.where(on_box, t2, t)
            hit = np.where(on_box[..., None], hit2, hit)
        img = texture(hit[..., 0], hit[..., 1], seed)
        views_out.append(View(f"v{i}", torch.from_numpy(img).float(), cam))
        depths.append(t)
    scene = Scene("planes", "folder", views_out, [], near=1.5, far=6.0)
    return scene, depths
