"""The random initialisation's box and point count (the reference's init, made scale-free)."""

from __future__ import annotations

import torch
from torch import Tensor

from sparsesplat.engine.scene import Scene
from sparsesplat.engine.train.config import InitConfig


def frusta_box(scene: Scene) -> tuple[Tensor, Tensor]:
    """A box around the training frusta between the scene's near and far bounds."""
    pts = []
    far = min(scene.far, scene.near * 1e3) if scene.near > 0 else scene.far
    for v in scene.train:
        cam = v.camera
        c2w = cam.camera_to_world.float()
        for u, w in ((0, 0), (cam.width, 0), (0, cam.height), (cam.width, cam.height)):
            ray = torch.tensor([(u - cam.cx) / cam.fx, (w - cam.cy) / cam.fy, 1.0])
            for z in (scene.near, far):
                pts.append(c2w[:3, :3] @ (ray * z) + c2w[:3, 3])
    p = torch.stack(pts)
    return p.min(dim=0).values, p.max(dim=0).values


def initial_point_count(
    cfg: InitConfig, lo: Tensor, hi: Tensor, camera_centers: list[Tensor]
) -> int:
    """The automatic initial Gaussian count: ``points_density`` x the init box's largest
    side over the median distance from the cameras to the box centre (a ratio of lengths, so
    the same scene in millimetres or metres gets the same count), clamped to the config's
    bounds."""
    centre = (lo.double() + hi.double()) / 2
    dist = torch.stack([(c.double() - centre).norm() for c in camera_centers]).median()
    side = float((hi.double() - lo.double()).max())
    n = round(cfg.points_density * side / float(dist)) if float(dist) > 0 else 0
    return min(max(n, cfg.points_min), cfg.points_max)
