"""User-supplied depth maps (uploaded with the images, carried as ``View.depth``)."""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import numpy as np
import torch

from sparsesplat.engine.errors import PriorError
from sparsesplat.engine.priors.base import PriorDepth
from sparsesplat.engine.scene import Scene


def user_priors(scene: Scene) -> list[PriorDepth]:
    """One prior per training view from its uploaded depth; pixels <= 0 or non-finite are
    invalid (confidence 0). Every training view must carry a depth map."""
    out = []
    for view in scene.train:
        if view.depth is None:
            raise PriorError(
                f"scene {scene.name!r}: training view {view.name!r} has no user depth map "
                "(add 'depth' to its frame in cameras.json, or choose another prior)"
            )
        depth = view.depth.float()
        h, w = view.image.shape[:2]
        if tuple(depth.shape) != (h, w):
            raise PriorError(f"view {view.name!r}: depth is {tuple(depth.shape)}, image {(h, w)}")
        valid = torch.isfinite(depth) & (depth > 0)
        depth = torch.where(valid, depth, torch.zeros_like(depth))
        out.append(PriorDepth(depth, valid.float(), metric=True, kind="user"))
    return out


def attach_depth_folder(scene: Scene, folder: str | Path) -> Scene:
    """``scene`` with ``folder/<view name>.npy`` ((H, W) float depth, view-space z) attached as
    the user depth of every training view, so ``depth_prior='user'`` trains against it.
    PriorError names the first view whose file is missing or has the wrong shape."""
    root = Path(folder)
    train = []
    for view in scene.train:
        path = root / f"{view.name}.npy"
        if not path.is_file():
            raise PriorError(f"scene {scene.name!r}: no depth file for view {view.name!r} ({path})")
        try:
            depth = torch.from_numpy(np.load(path, allow_pickle=False).astype(np.float32))
        except (OSError, ValueError) as exc:
            raise PriorError(f"{path}: not a readable .npy depth map ({exc})") from exc
        h, w = view.image.shape[:2]
        if tuple(depth.shape) != (h, w):
            raise PriorError(f"{path}: depth is {tuple(depth.shape)}, image {(h, w)}")
        train.append(replace(view, depth=depth))
    return replace(scene, train=train)
