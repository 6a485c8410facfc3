"""The run's data on its device: what the trainer trains against, prepared once at set-up.

The scene re-composited on the run's one background, the training cameras and target images on
the device, the targets' SSIM statistics, the initial box, the scene extent the learning rates
scale with, the near distance and the rasterizer bound to it. Nothing here draws a random
number: preparing the data leaves the run's generator as it found it.
"""

from __future__ import annotations

from dataclasses import dataclass

import torch
from torch import Tensor

from sparsesplat.engine.camera import Camera
from sparsesplat.engine.datasets.common import with_background
from sparsesplat.engine.losses import SSIMTarget
from sparsesplat.engine.model.raster import Raster, bind_raster
from sparsesplat.engine.scene import Scene
from sparsesplat.engine.train.config import TrainConfig
from sparsesplat.engine.train.init.random_init import frusta_box


@dataclass
class RunData:
    """What :func:`run_data` prepares (the trainer keeps each field as its own attribute)."""

    scene: Scene
    """The scene, images with alpha re-composited on :attr:`background`."""
    background: Tensor
    """(3,) on the device: the one background of targets and renders."""
    cameras: list[Camera]
    """The training cameras, float32 on the device."""
    images: list[Tensor]
    """The training targets, (3, H, W) float on the device."""
    ssim_targets: list[SSIMTarget]
    """The targets' fixed SSIM statistics."""
    box: tuple[Tensor, Tensor]
    """(lo, hi) of the initial box, on the CPU."""
    extent: float
    """Scene extent (1.1 x max train-camera distance from their mean), scales LRs."""
    raster_near: float
    """View-z culling distance used by every render of this run."""
    raster: Raster
    """The run's rasterizer (the parts, the evaluation and the trainer's render share it)."""


def run_background(scene: Scene, cfg: TrainConfig) -> Tensor:
    """The run's (3,) float32 background: ``cfg.background``, the scene's when None, or for
    ``"mean"`` the mean colour of the training photos (each photo weighed equally)."""
    if cfg.background == "mean":
        means = [v.image.reshape(-1, 3).double().mean(dim=0) for v in scene.train]
        return torch.stack(means).mean(dim=0).float()
    bg = cfg.background if cfg.background is not None else scene.background
    return torch.as_tensor(bg, dtype=torch.float32)


def run_data(scene: Scene, cfg: TrainConfig, device: torch.device) -> RunData:
    """Prepare ``scene``'s training views for a run of ``cfg`` on ``device``."""
    # One background for targets and renders: images with alpha are re-composited on it.
    scene = with_background(scene, run_background(scene, cfg))
    background = scene.background.float().reshape(3).to(device)
    cameras = [v.camera.to(device, torch.float32) for v in scene.train]
    images = [v.image.permute(2, 0, 1).contiguous().float().to(device) for v in scene.train]
    # The targets' SSIM statistics are fixed: computed once, not every iteration.
    ssim_targets = [SSIMTarget(img) for img in images]
    centers = torch.stack([c.center.float() for c in cameras])
    radius = float((centers - centers.mean(dim=0)).norm(dim=1).max()) * 1.1
    if cfg.init.box is not None:
        lo, hi = (torch.tensor(c, dtype=torch.float32) for c in cfg.init.box)
    elif scene.init_box is not None:
        lo, hi = (torch.tensor(c, dtype=torch.float32) for c in scene.init_box)
    else:
        lo, hi = frusta_box(scene)
    if radius <= 0:  # a single view (or coincident cameras): fall back to the box size
        radius = float((hi - lo).max()) * 0.5
    near = cfg.raster.near if cfg.raster.near is not None else 0.2 * scene.near
    raster_near = near if near > 0 else 0.01
    raster = bind_raster(raster_near, cfg.raster.eps2d, cfg.raster.backend)
    return RunData(
        scene, background, cameras, images, ssim_targets, (lo.cpu(), hi.cpu()), radius,
        raster_near, raster,
    )  # fmt: skip
