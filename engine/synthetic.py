"""Tiny synthetic scenes (a random Gaussian blob seen by a few cameras) for tests and benchmarks."""

from __future__ import annotations

import math

import torch
from torch import Tensor

from sparsesplat.engine.camera import Camera
from sparsesplat.engine.raster import rasterize
from sparsesplat.engine.scene import Scene, View


def look_at(eye: Tensor, target: Tensor) -> Tensor:
    """World-to-camera (OpenCV axes) for a camera at ``eye`` looking at ``target``, y down."""
    z = torch.nn.functional.normalize(target - eye, dim=0)
    up = torch.tensor([0.0, -1.0, 0.0])
    x = torch.nn.functional.normalize(torch.linalg.cross(up, z), dim=0)
    y = torch.linalg.cross(z, x)
    r = torch.stack([x, y, z])
    w2c = torch.eye(4)
    w2c[:3, :3] = r
    w2c[:3, 3] = -r @ eye
    return w2c


def make_cameras(n: int, width: int, height: int, scale: float = 1.0) -> list[Camera]:
    """``n`` cameras on an arc at distance 4*scale looking at the origin."""
    cams = []
    f = 0.9 * width
    for k in range(n):
        a = -0.5 + 1.0 * k / max(n - 1, 1)
        eye = torch.tensor([4.0 * math.sin(a), 0.3 * (k % 2), -4.0 * math.cos(a)]) * scale
        cams.append(
            Camera(look_at(eye, torch.zeros(3)), f, f, width / 2, height / 2, width, height)
        )
    return cams


def make_scene(
    seed: int = 0,
    width: int = 32,
    height: int = 24,
    n_train: int = 3,
    n_test: int = 2,
    n_gaussians: int = 60,
    scale: float = 1.0,
    background: float = 0.0,
    image_fill: float | None = None,
) -> tuple[Scene, list[Tensor]]:
    """A scene rendered from a random blob of Gaussians, plus the true depth of each training
    view (a perfect prior). ``image_fill`` replaces every image with that constant colour."""
    g = torch.Generator().manual_seed(seed)
    means = (torch.rand(n_gaussians, 3, generator=g) - 0.5) * 2.0 * scale
    log_scales = torch.full((n_gaussians, 3), math.log(0.25 * scale))
    quats = torch.nn.functional.normalize(torch.randn(n_gaussians, 4, generator=g), dim=1)
    opac = torch.full((n_gaussians,), 2.0)
    colors = torch.rand(n_gaussians, 3, generator=g)
    bg = torch.full((3,), background)
    # Interleave so train and test views alternate around the arc.
    cams = make_cameras(n_train + n_test, width, height, scale)
    train_idx = list(range(0, n_train + n_test, 2))[:n_train]
    rest = [i for i in range(n_train + n_test) if i not in train_idx]
    train_idx += rest[: n_train - len(train_idx)]
    test_idx = [i for i in range(n_train + n_test) if i not in train_idx]
    views, depths = {}, {}
    for i, cam in enumerate(cams):
        with torch.no_grad():
            out = rasterize(means, log_scales, quats, opac, colors, cam, bg, near=0.01 * scale)
        img = out.image.permute(1, 2, 0).clamp(0, 1).contiguous()
        if image_fill is not None:
            img = torch.full_like(img, image_fill)
        views[i] = View(name=f"v{i}", image=img, camera=cam)
        depths[i] = out.depth[0] / out.alpha[0].clamp_min(1e-3)
    box = ((-1.5 * scale,) * 3, (1.5 * scale,) * 3)
    scene = Scene(
        name=f"synthetic{seed}",
        format="folder",
        train=[views[i] for i in train_idx],
        test=[views[i] for i in test_idx],
        background=bg,
        near=0.5 * scale,
        far=10.0 * scale,
        init_box=box,
    )
    return scene, [depths[i] for i in train_idx]
