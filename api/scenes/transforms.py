"""NeRF-synthetic (``transforms_{train,test}.json``) and instant-ngp / nerfstudio
(``transforms.json``) scenes: OpenGL camera-to-world ``transform_matrix`` per frame, intrinsics
per frame or in the header, optional OpenCV lens distortion (k1, k2, p1, p2)."""

from __future__ import annotations

import json
import math
from pathlib import Path
from typing import Any

from sparsesplat.api.scenes.errors import SceneFormatError

BLENDER_NEAR, BLENDER_FAR = 2.0, 6.0
"""NeRF-synthetic's depth range."""
UNIT_CUBE = ((-1.0, -1.0, -1.0), (1.0, 1.0, 1.0))
"""The [-1, 1] cube DTU's and NeRF-synthetic's objects lie in (their initialisation box)."""


def read_transforms(path: Path) -> dict[str, Any]:
    """Parse a transforms JSON; a missing or malformed file raises naming ``path``."""
    if not path.is_file():
        raise SceneFormatError(f"{path}: file not found")
    try:
        meta = json.loads(path.read_text())
    except (OSError, ValueError) as exc:
        raise SceneFormatError(f"{path}: cannot parse JSON ({exc})") from exc
    if not isinstance(meta, dict) or not isinstance(meta.get("frames"), list):
        raise SceneFormatError(f"{path}: no 'frames' list")
    return meta


def frame_image_path(root: Path, frame: dict[str, Any], source: str) -> Path:
    """The image file of a frame's ``file_path`` (NeRF-synthetic omits the .png suffix)."""
    rel = frame.get("file_path")
    if not isinstance(rel, str):
        raise SceneFormatError(f"{source}: frame without a 'file_path'")
    path = (root / rel).resolve()
    if path.suffix == "" or not path.is_file():
        for suffix in (".png", ".jpg", ".jpeg"):
            if path.with_name(path.name + suffix).is_file():
                return path.with_name(path.name + suffix)
    if not path.is_file():
        raise SceneFormatError(f"{source}: image {rel!r} not found under {root}")
    return path


def intrinsics(
    meta: dict[str, Any], frame: dict[str, Any], width: int, height: int, source: str
) -> tuple[float, float, float, float]:
    """fx, fy, cx, cy of one frame for an image of ``width`` x ``height``.

    Per-frame keys override the header's. ``fl_x/fl_y/cx/cy`` are in pixels of the stored size
    ``w/h`` and are rescaled when the image differs; without ``fl_x`` the focal comes from
    ``camera_angle_x`` (NeRF-synthetic) and the principal point defaults to the centre."""

    def get(key: str) -> Any:
        return frame.get(key, meta.get(key))

    sx, sy = width / float(get("w") or width), height / float(get("h") or height)
    try:
        if get("fl_x") is not None:
            fx = float(get("fl_x")) * sx
            fy = float(get("fl_y") if get("fl_y") is not None else get("fl_x")) * sy
        elif get("camera_angle_x") is not None:
            fx = 0.5 * width / math.tan(0.5 * float(get("camera_angle_x")))
            angle_y = get("camera_angle_y")
            fy = fx if angle_y is None else 0.5 * height / math.tan(0.5 * float(angle_y))
        else:
            raise SceneFormatError(f"{source}: no focal length (fl_x or camera_angle_x)")
        cx = float(get("cx")) * sx if get("cx") is not None else width / 2.0
        cy = float(get("cy")) * sy if get("cy") is not None else height / 2.0
    except (TypeError, ValueError) as exc:
        if isinstance(exc, SceneFormatError):
            raise
        raise SceneFormatError(f"{source}: malformed intrinsics ({exc})") from exc
    if not all(math.isfinite(v) for v in (fx, fy, cx, cy)) or fx <= 0 or fy <= 0:
        raise SceneFormatError(f"{source}: invalid intrinsics fx={fx} fy={fy} cx={cx} cy={cy}")
    return fx, fy, cx, cy


def distortion(
    meta: dict[str, Any], frame: dict[str, Any], source: str = "transforms.json"
) -> tuple[float, float, float, float]:
    """OpenCV (k1, k2, p1, p2) of a frame (per-frame keys over the header's; zeros if absent)."""
    out = []
    for key in ("k1", "k2", "p1", "p2"):
        value = frame.get(key, meta.get(key, 0.0))
        try:
            out.append(float(value or 0.0))
        except (TypeError, ValueError) as exc:
            raise SceneFormatError(f"{source}: distortion {key}={value!r} is not a number") from exc
    if not all(math.isfinite(v) for v in out):
        raise SceneFormatError(f"{source}: distortion coefficients {out} contain NaN or inf")
    return out[0], out[1], out[2], out[3]


def distorted_pixels(
    width: int,
    height: int,
    k: tuple[float, float, float, float],
    coeffs: tuple[float, float, float, float],
) -> tuple[Any, Any]:
    """Where the lens imaged each ideal pinhole pixel: (x, y) continuous pixel coordinates,
    each (H, W) float64 (NumPy). An undistorted image samples the photo there."""
    import numpy as np

    fx, fy, cx, cy = k
    k1, k2, p1, p2 = coeffs
    v, u = np.mgrid[0:height, 0:width].astype(np.float64) + 0.5
    x, y = (u - cx) / fx, (v - cy) / fy
    r2 = x * x + y * y
    radial = 1.0 + k1 * r2 + k2 * r2 * r2
    xd = x * radial + 2 * p1 * x * y + p2 * (r2 + 2 * x * x)
    yd = y * radial + p1 * (r2 + 2 * y * y) + 2 * p2 * x * y
    return xd * fx + cx, yd * fy + cy
