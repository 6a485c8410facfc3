"""DTU scans in the NeuS/IDR layout: ``cameras_sphere.npz``, ``images/`` (or ``image/``),
``mask/``. ``world_mat_i @ scale_mat_i`` projects the normalised frame (the object inside the
unit sphere) to pixels; cameras are expressed in that frame."""

from __future__ import annotations

from pathlib import Path
from typing import Any

from sparsesplat.api.scenes.errors import SceneFormatError

UNIT_SPHERE_RADIUS = 1.0
"""NeuS's scale_mat maps the object of interest into the sphere of this radius."""
MIN_NEAR = 0.05
"""The smallest near bound (a camera inside the sphere would otherwise give near <= 0)."""


def image_folder(root: Path) -> Path:
    """``images/`` (this dataset copy) or ``image/`` (canonical NeuS)."""
    return root / "images" if (root / "images").is_dir() else root / "image"


def mask_path(root: Path, index: int, image: Path) -> Path | None:
    """The object mask of camera ``index``: ``mask/NNN.png`` (NeuS) or the image's own name,
    or None when the folder has none."""
    for folder in ("mask", "masks"):
        for name in (f"{index:03d}.png", image.name):
            if (root / folder / name).is_file():
                return root / folder / name
    return None


def read_cameras(path: Path) -> dict[str, Any]:
    """The arrays of ``cameras_sphere.npz`` by name (NumPy)."""
    import numpy as np

    if not path.is_file():
        raise SceneFormatError(f"{path}: file not found")
    try:
        return dict(np.load(path, allow_pickle=False))
    except (OSError, ValueError) as exc:
        raise SceneFormatError(f"{path}: cannot read ({exc})") from exc


def projection(cams: dict[str, Any], index: int, source: str) -> Any:
    """The 3x4 projection ``world_mat @ scale_mat`` of camera ``index`` (float64)."""
    import numpy as np

    keys = (f"world_mat_{index}", f"scale_mat_{index}")
    missing = [k for k in keys if k not in cams]
    if missing:
        raise SceneFormatError(f"{source}: missing {', '.join(missing)}")
    mats = [np.asarray(cams[k], dtype=np.float64) for k in keys]
    if any(m.shape != (4, 4) or not np.all(np.isfinite(m)) for m in mats):
        raise SceneFormatError(f"{source}: camera {index}: matrices must be finite 4x4")
    return (mats[0] @ mats[1])[:3]


def rq_decomposition(matrix: Any) -> tuple[Any, Any]:
    """Factor a 3x3 matrix as K @ R with K upper-triangular (positive diagonal) and R
    orthonormal, via QR of the row-reversed transpose (no OpenCV needed)."""
    import numpy as np

    flip = np.flipud(np.eye(3))
    q, r = np.linalg.qr((flip @ matrix).T)
    k = flip @ r.T @ flip
    rot = flip @ q.T
    # Make K's diagonal positive; D = diag(sign) satisfies D @ D = I.
    d = np.diag(np.sign(np.diag(k)))
    return k @ d, d @ rot


def decompose_projection(p: Any, source: str) -> tuple[Any, Any]:
    """A 3x4 projection P = s K [R | t] -> (K 3x3 with K[2, 2] = 1, OpenCV world-to-camera
    4x4), both float64; SceneFormatError for a degenerate or skewed projection."""
    import numpy as np

    k, rot = rq_decomposition(p[:, :3])
    if abs(k[2, 2]) < 1e-12:
        raise SceneFormatError(f"{source}: projection matrix is degenerate (K[2,2] = 0)")
    scale = k[2, 2]
    k = k / scale
    if np.linalg.det(rot) < 0:  # P and -P are the same projection; choose the proper rotation
        rot, scale = -rot, -scale
    t = np.linalg.solve(k, p[:, 3] / scale)
    if abs(k[0, 1]) > 1e-3 * abs(k[0, 0]):
        raise SceneFormatError(
            f"{source}: projection has skew {k[0, 1]:.3g}, which is not supported"
        )
    w2c = np.eye(4)
    w2c[:3, :3], w2c[:3, 3] = rot, t
    return k, w2c


def bounds(centre_distances: list[float]) -> tuple[float, float]:
    """The scan's near/far: the unit sphere seen from cameras at these distances from its
    centre."""
    near = max(MIN_NEAR, min(centre_distances) - UNIT_SPHERE_RADIUS)
    return near, max(centre_distances) + UNIT_SPHERE_RADIUS
