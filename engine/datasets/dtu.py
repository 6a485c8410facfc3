"""DTU scans in the NeuS/IDR layout: ``cameras_sphere.npz``, ``images/`` (or ``image/``),
``mask/``. Poses are expressed in the normalised frame of ``scale_mat`` (object in the unit
sphere)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import torch

from sparsesplat.engine.camera import Camera
from sparsesplat.engine.camera_convert import camera_from_neus
from sparsesplat.engine.datasets.common import load_view
from sparsesplat.engine.datasets.splits import dtu_split
from sparsesplat.engine.errors import CameraError, SceneError
from sparsesplat.engine.images import image_size, list_images
from sparsesplat.engine.scene import Scene

BLACK = (0.0, 0.0, 0.0)
UNIT_SPHERE_RADIUS = 1.0
"""NeuS's scale_mat maps the object of interest into the unit sphere."""


def _mask_path(root: Path, index: int, image: Path) -> Path | None:
    """The mask of camera ``index``: ``mask/NNN.png`` (NeuS) or the image's own name."""
    for folder in ("mask", "masks"):
        for name in (f"{index:03d}.png", image.name):
            if (root / folder / name).is_file():
                return root / folder / name
    return None


def image_folder(root: Path) -> Path:
    """``images/`` (this dataset copy) or ``image/`` (canonical NeuS)."""
    return root / "images" if (root / "images").is_dir() else root / "image"


def load_dtu(root: Path, views: int, downscale: int = 1) -> Scene:
    """Load a DTU scan with the RegNeRF split (train 25, 22, 28; the 25 test IDs), black
    background, object masks on every view."""
    npz_path = root / "cameras_sphere.npz"
    if not npz_path.is_file():
        raise SceneError(f"{npz_path}: file not found")
    files = list_images(image_folder(root))
    try:
        cams_npz = dict(np.load(npz_path, allow_pickle=False))
    except (OSError, ValueError) as exc:
        raise SceneError(f"{npz_path}: cannot read ({exc})") from exc
    train_idx, test_idx = dtu_split(len(files), views, str(root))
    width, height = image_size(files[0])

    def camera(i: int) -> Camera:
        keys = (f"world_mat_{i}", f"scale_mat_{i}")
        missing = [k for k in keys if k not in cams_npz]
        if missing:
            raise SceneError(f"{npz_path}: missing {', '.join(missing)}")
        try:
            return camera_from_neus(
                cams_npz[keys[0]], cams_npz[keys[1]], width, height, f"{npz_path} camera {i}"
            )
        except CameraError as exc:
            raise SceneError(str(exc)) from exc

    def view(i: int):  # type: ignore[no-untyped-def]
        mask = _mask_path(root, i, files[i])
        if mask is None:
            raise SceneError(f"{root / 'mask'}: no mask for camera {i} ({files[i].name})")
        return load_view(files[i].stem, files[i], camera(i), BLACK, downscale, mask_path=mask)

    train = [view(i) for i in train_idx]
    test = [view(i) for i in test_idx]
    dists = [float(torch.linalg.norm(v.camera.center)) for v in train + test]
    near = max(0.05, min(dists) - UNIT_SPHERE_RADIUS)
    far = max(dists) + UNIT_SPHERE_RADIUS
    return Scene(
        name=root.name,
        format="dtu",
        train=train,
        test=test,
        background=torch.tensor(BLACK),
        near=near,
        far=far,
        init_box=((-1.0, -1.0, -1.0), (1.0, 1.0, 1.0)),
        train_indices=train_idx,
        test_indices=test_idx,
    )


DTU_DARK_THRESHOLD = 30.0 / 255.0
"""Max-RGB below which a DTU training pixel may be background (the reference uses 15/255
for scan110)."""
DTU_DARK_RUN = 49
"""A dark pixel is background only if this many pixels directly above it are dark too."""


def dtu_background_mask(
    image: torch.Tensor, threshold: float = DTU_DARK_THRESHOLD, run: int = DTU_DARK_RUN
) -> torch.Tensor:
    """The reference's DTU training background mask for an (H, W, 3) image: pixels whose max
    channel is below ``threshold`` and whose ``run`` upper neighbours in the same column are
    also dark (rows nearer the top than ``run`` need only the rows that exist). The black
    backdrop of DTU passes; dark texture on the object (short dark runs) does not."""
    dark = image.max(dim=-1).values < threshold
    mask = dark.clone()
    for shift in range(1, run + 1):
        if shift >= dark.shape[0]:
            break
        mask[shift:] &= dark[:-shift]
    return mask
