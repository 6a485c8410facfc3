"""LLFF scenes: ``poses_bounds.npy`` plus an ``images_N`` folder.

Each ``poses_bounds.npy`` row is a 3x5 matrix [R | t | hwf] flattened row-major, then near and
far. The rotation columns are the camera's [down, right, back] axes in world coordinates, t is
the camera centre and hwf the FULL-resolution height, width and focal length; the stored image
folders are shrunk copies, so the focal is rescaled to the image actually read.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

from sparsesplat.api.scenes.errors import SceneFormatError

IMAGE_DIRS = ("images_8", "images_4", "images_2", "images")
"""Image folders in order of preference: the paper's 8x first, full resolution last."""


def find_image_dir(root: Path) -> Path:
    """The first existing folder of :data:`IMAGE_DIRS` under ``root``."""
    for name in IMAGE_DIRS:
        if (root / name).is_dir():
            return root / name
    raise SceneFormatError(f"{root}: no image folder (looked for {', '.join(IMAGE_DIRS)})")


def read_poses_bounds(path: Path) -> Any:
    """``poses_bounds.npy`` as a float64 (N, 17) array (NumPy)."""
    import numpy as np

    if not path.is_file():
        raise SceneFormatError(f"{path}: file not found")
    try:
        pb = np.asarray(np.load(path, allow_pickle=False), dtype=np.float64)
    except (OSError, ValueError) as exc:
        raise SceneFormatError(f"{path}: cannot read ({exc})") from exc
    if pb.ndim != 2 or pb.shape[1] != 17:
        raise SceneFormatError(f"{path}: expected an (N, 17) array, got shape {pb.shape}")
    if not np.all(np.isfinite(pb)):
        bad = int(np.where(~np.isfinite(pb).all(axis=1))[0][0])
        raise SceneFormatError(f"{path}: row {bad} contains NaN or inf")
    return pb


def camera_to_world(pose34: Any) -> Any:
    """LLFF 3x4 [down, right, back | centre] -> OpenCV camera-to-world 4x4 (float64)."""
    import numpy as np

    m = np.asarray(pose34, dtype=np.float64)
    down, right, back, centre = m[:, 0], m[:, 1], m[:, 2], m[:, 3]
    c2w = np.eye(4)
    # OpenCV axes: x = right, y = down, z = forward = -back.
    c2w[:3, 0], c2w[:3, 1], c2w[:3, 2], c2w[:3, 3] = right, down, -back, centre
    return c2w


def intrinsics(row: Any, width: int, height: int, source: str) -> tuple[float, float, float, float]:
    """fx, fy, cx, cy of one ``poses_bounds.npy`` row for an image of ``width`` x ``height``:
    the full-resolution focal rescaled, the principal point at the image centre. The image
    must have the full-resolution aspect (within 1%)."""
    h_full, w_full, focal = (float(v) for v in row[:15].reshape(3, 5)[:, 4])
    scale_y, scale_x = height / h_full, width / w_full
    if abs(scale_x - scale_y) > 0.01 * max(scale_x, scale_y):
        raise SceneFormatError(
            f"{source}: full-resolution size {w_full:.0f}x{h_full:.0f} does not have "
            f"the aspect of the images ({width}x{height})"
        )
    return focal * scale_x, focal * scale_y, width / 2.0, height / 2.0
