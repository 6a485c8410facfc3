"""In-memory scene: posed views with their images, split into training and held-out views."""

from __future__ import annotations

from dataclasses import dataclass, field

import torch
from torch import Tensor

from sparsesplat.engine.camera import Camera


@dataclass
class View:
    """One posed photograph."""

    name: str
    """Stable identifier, usually the image file stem."""
    image: Tensor
    """(H, W, 3) float32 RGB in [0, 1], already composited on the scene background."""
    camera: Camera
    """Pose and intrinsics; ``camera.width/height`` equal the image size."""
    mask: Tensor | None = None
    """(H, W) bool object mask where the format provides one (DTU), else None."""
    depth: Tensor | None = None
    """(H, W) float32 user-supplied depth map (view-space z) where one was uploaded, else None."""
    alpha: Tensor | None = None
    """(H, W) float32 alpha of the source image where it had one (``image`` is composited on
    the scene background with it, so the background can be changed exactly), else None."""


@dataclass
class Scene:
    """A posed multi-view scene with the paper's split applied."""

    name: str
    """Scene name (folder name)."""
    format: str
    """Source layout: 'llff', 'blender', 'dtu', 'ngp' or 'folder' (the API upload layout)."""
    train: list[View]
    """Training views (the sparse input)."""
    test: list[View]
    """Held-out views used for evaluation; may be empty for user uploads."""
    background: Tensor = field(default_factory=lambda: torch.zeros(3))
    """(3,) RGB the images were composited on and the renderer should blend onto."""
    near: float = 0.01
    """Near bound of the scene depth range in scene units (informative; used by priors)."""
    far: float = 100.0
    """Far bound of the scene depth range in scene units."""
    init_box: tuple[tuple[float, float, float], tuple[float, float, float]] | None = None
    """(min xyz, max xyz) box for random initialization, when the format gives one."""
    train_indices: list[int] = field(default_factory=list)
    """Indices of the training views in the source's sorted image list."""
    test_indices: list[int] = field(default_factory=list)
    """Indices of the held-out views in the source's sorted image list."""
    sparse_points: tuple[Tensor, Tensor] | None = None
    """(N, 3) points and (N, 3) RGB colours in [0, 1] from structure from motion, where the
    cameras were estimated from the photos (``engine/sfm``); the trainer's ``init='sparse'``
    starts from them."""
    pose_std_deg: float | None = None
    """The largest orientation uncertainty among the training cameras (one standard
    deviation, degrees; ``rotation_std_deg`` of ``cameras.json``, written where the cameras
    were estimated from the photos); None where no frame gives one."""
    render_path: list[Camera] = field(default_factory=list)
    """The format's own novel-view camera path (LLFF: the reference's 180-frame spiral through
    every image's pose, ``engine/camera_path.py``); empty where the format defines none."""
