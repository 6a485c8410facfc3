"""The training views of a shared scene as a user's photos, and their cameras estimated from
those photos alone: what the camera benchmarks (``benchmarks/cameras.py``) and the training
comparison (``benchmarks/camera_training.py``) start from."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np


def attempts_matching_at(match_side: int | None) -> tuple[Any, ...]:
    """The estimate's attempts with the learned one matching photos enlarged to
    ``match_side`` pixels (None: the attempts as they are). How firm an estimate is shows in
    how much it moves when only the matcher's working size changes."""
    import dataclasses

    from sparsesplat.engine.sfm.attempts import ATTEMPTS

    if match_side is None:
        return ATTEMPTS
    return tuple(
        dataclasses.replace(a, match_min_side=match_side) if a.matcher is not None else a
        for a in ATTEMPTS
    )


def write_training_photos(scene: Any, folder: Path, scale: int = 1) -> list[Path]:
    """``scene``'s training views as 8-bit PNGs ``000.png``, ``001.png``, ... in ``folder``:
    the photos a user would upload, enlarged ``scale`` times (bicubic) when it is over 1."""
    from PIL import Image

    from sparsesplat.engine.sfm.enlarge import write_enlarged

    if scale < 1:
        raise ValueError(f"scale must be a whole number >= 1, got {scale}")
    paths = []
    for i, view in enumerate(scene.train):
        pixels = (view.image.numpy() * 255 + 0.5).clip(0, 255).astype(np.uint8)
        paths.append(folder / f"{i:03d}.png")
        Image.fromarray(pixels).save(paths[-1])
    if scale > 1:  # the estimate's own enlarging, in place
        write_enlarged(folder, [p.name for p in paths], folder, scale)
    return paths


def estimate_views(
    scene: Any, given: bool, threads: int, tmp: Path, match_side: int | None = None,
    scale: int = 1,
) -> Any:  # fmt: skip
    """The cameras of ``scene``'s training views estimated from their pixels alone (PNGs in
    ``tmp``, enlarged ``scale`` times), with the dataset's intrinsics (scaled alike) held
    fixed when ``given``. Pixel coordinates scale exactly: the centres are at +0.5 on both
    sides of the resize."""
    from sparsesplat.api.cameras import Intrinsics
    from sparsesplat.engine.sfm import estimate_cameras

    paths = write_training_photos(scene, tmp, scale)
    cam = scene.train[0].camera
    k = float(scale)
    intrinsics = (
        Intrinsics(fx=cam.fx * k, fy=cam.fy * k, cx=cam.cx * k, cy=cam.cy * k) if given else None
    )
    return estimate_cameras(
        paths, intrinsics, threads=threads, attempts=attempts_matching_at(match_side)
    )


def placed_views(scene: Any, estimate: Any) -> tuple[Any, list[int]]:
    """``scene`` with only the training views that ``estimate`` placed (the photos it left
    out by name dropped), and their indices in the scene's training views: both runs of a
    comparison then train on the same photos, so that the difference is the cameras'."""
    import dataclasses

    placed = [i for i, p in enumerate(estimate.photos) if p.placed]
    if len(placed) == len(scene.train):
        return scene, placed
    train = [scene.train[i] for i in placed]
    indices = [scene.train_indices[i] for i in placed] if scene.train_indices else []
    return dataclasses.replace(scene, train=train, train_indices=indices), placed
