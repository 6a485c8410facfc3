"""The sparse points beside an estimated ``cameras.json``, and the trainer's init from them.

Structure from motion triangulates a few hundred to a few thousand coloured points; 3D
Gaussian Splatting normally starts from exactly these. They are stored as
``sparse_points.npz`` (``points`` (N, 3) float32 in the cameras' frame, ``colours`` (N, 3)
float32 RGB in [0, 1]) in the scene folder, and read back by the folder loader.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import torch
from torch import Tensor

from sparsesplat.engine.errors import SceneError

SPARSE_POINTS_FILE = "sparse_points.npz"
"""File name of the sparse points inside a scene folder."""


def write_sparse_points(folder: Path, points: np.ndarray, colours: np.ndarray) -> Path:
    """Write ``points`` and ``colours`` (N, 3 each) into ``folder``; the file's path."""
    if points.shape != colours.shape or points.ndim != 2 or points.shape[1] != 3:
        raise ValueError(f"points {points.shape} and colours {colours.shape} must both be (N, 3)")
    path = folder / SPARSE_POINTS_FILE
    np.savez(path, points=points.astype(np.float32), colours=colours.astype(np.float32))
    return path


def read_sparse_points(folder: Path) -> tuple[Tensor, Tensor] | None:
    """The scene folder's sparse points and colours as float32 tensors (None without a file);
    SceneError when the file is malformed."""
    path = folder / SPARSE_POINTS_FILE
    if not path.is_file():
        return None
    try:
        with np.load(path) as data:
            points, colours = np.asarray(data["points"]), np.asarray(data["colours"])
    except (OSError, KeyError, ValueError) as exc:
        raise SceneError(f"{path.name}: unreadable sparse points ({exc})") from exc
    if points.ndim != 2 or points.shape[1] != 3 or colours.shape != points.shape:
        raise SceneError(f"{path.name}: points {points.shape} and colours {colours.shape}")
    if not (np.isfinite(points).all() and np.isfinite(colours).all()):
        raise SceneError(f"{path.name}: points or colours contain NaN or infinity")
    return (
        torch.from_numpy(points.astype(np.float32)),
        torch.from_numpy(colours.astype(np.float32).clip(0.0, 1.0)),
    )


def sparse_initial_points(
    sparse: tuple[Tensor, Tensor] | None, target: int, generator: torch.Generator
) -> tuple[Tensor, Tensor]:
    """The trainer's ``init='sparse'``: every sparse point with its colour, and, when there
    are fewer than ``target``, copies of random ones jittered by a fraction of the distance to
    their nearest neighbour (so the densification starts from a cloud, not a few hundred
    isolated points). SceneError when the scene has no sparse points."""
    if sparse is None or len(sparse[0]) == 0:
        raise SceneError(
            f"init 'sparse' needs the scene's sparse points ({SPARSE_POINTS_FILE}, written when "
            "the cameras were estimated from the photos)"
        )
    points, colours = sparse
    extra = target - len(points)
    if extra <= 0:
        return points.clone(), colours.clone()
    spacing = _nearest_distance(points)
    pick = torch.randint(len(points), (extra,), generator=generator)
    jitter = torch.randn(extra, 3, generator=generator) * 0.5 * spacing[pick, None]
    return torch.cat([points, points[pick] + jitter]), torch.cat([colours, colours[pick]])


def _nearest_distance(points: Tensor, chunk: int = 1024) -> Tensor:
    """Distance of each point to its nearest other point (1 for a lone point), in chunks so
    memory stays O(chunk x N)."""
    if len(points) < 2:
        return torch.ones(len(points))
    out = []
    for start in range(0, len(points), chunk):
        d = torch.cdist(points[start : start + chunk], points)
        rows = torch.arange(d.shape[0])
        d[rows, rows + start] = float("inf")
        out.append(d.min(dim=1).values)
    return torch.cat(out)
