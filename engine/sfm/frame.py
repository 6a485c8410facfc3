"""The frame an estimated scene is stored in: origin at the points, unit scale, bounds.

COLMAP's frame is arbitrary (its first pair's camera, a scale of its choosing). The trainer's
defaults expect the DTU-like frame the datasets use: the scene within about [-1, 1] and the
cameras outside it. So the points' robust centre becomes the origin, the first photo's axes
the world axes, and the scale puts the middle 96% of the points within [-1, 1] on the widest
axis. Near/far come from the points' depths in the cameras, the init box from their extent.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from sparsesplat.engine.sfm.reconstruct import Reconstruction

ROBUST_PERCENT = 2.0
"""Percentile trimmed at each end of the points (stray far triangulations)."""
BOX_MARGIN = 0.1
"""The init box is the trimmed points' box grown by this fraction of its size on each side."""
NEAR_FACTOR = 0.8
"""Near bound: this times the nearest trimmed point depth."""
FAR_FACTOR = 1.25
"""Far bound: this times the farthest trimmed point depth."""


@dataclass
class Normalised:
    """A reconstruction in the stored frame."""

    world_to_camera: dict[int, np.ndarray]
    """Photo index -> (4, 4) float64 world-to-camera, OpenCV axes."""
    points: np.ndarray
    """(N, 3) float64 points."""
    near: float
    """Nearest scene depth from any camera."""
    far: float
    """Farthest scene depth from any camera."""
    init_box: tuple[tuple[float, float, float], tuple[float, float, float]]
    """The box the points lie in (with a margin)."""
    scale: float
    """COLMAP units -> stored units."""


def normalise(rec: Reconstruction) -> Normalised:
    """``rec`` moved to the stored frame: x' = s (R0 x - m), R0 the first photo's rotation,
    m the per-axis median of the rotated points."""
    lo_q, hi_q = ROBUST_PERCENT, 100.0 - ROBUST_PERCENT
    first = min(rec.world_to_camera)
    r0 = rec.world_to_camera[first][:3, :3]
    rotated = rec.points @ r0.T
    centre = np.median(rotated, axis=0)
    rotated -= centre
    half = (np.percentile(rotated, hi_q, axis=0) - np.percentile(rotated, lo_q, axis=0)) / 2
    scale = 1.0 / float(max(half.max(), 1e-12))
    points = rotated * scale
    poses = {}
    for i, w2c in rec.world_to_camera.items():
        r = w2c[:3, :3] @ r0.T
        out = np.eye(4)
        out[:3, :3] = r
        out[:3, 3] = scale * (r @ centre + w2c[:3, 3])
        poses[i] = out
    depths = np.concatenate([points @ p[:3, :3].T[:, 2] + p[2, 3] for p in poses.values()])
    depths = depths[depths > 0]
    near = NEAR_FACTOR * float(np.percentile(depths, lo_q))
    far = FAR_FACTOR * float(np.percentile(depths, hi_q))
    low = np.percentile(points, lo_q, axis=0)
    high = np.percentile(points, hi_q, axis=0)
    pad = BOX_MARGIN * (high - low)
    box = (
        tuple(float(v) for v in low - pad),
        tuple(float(v) for v in high + pad),
    )
    return Normalised(poses, points, near, far, box, scale)  # type: ignore[arg-type]
