"""DTU scans in the NeuS/IDR layout: ``cameras_sphere.npz``, ``images/`` (or ``image/``),
``mask/``. Poses are expressed in the normalised frame of ``scale_mat`` (object in the unit
sphere)."""

from __future__ import annotations

from pathlib import Path

import torch

from sparsesplat.api.scenes import dtu as dtu_format
from sparsesplat.api.scenes.transforms import UNIT_CUBE
from sparsesplat.engine.camera import Camera
from sparsesplat.engine.camera_convert import camera_from_projection
from sparsesplat.engine.datasets.common import load_view, split_scene
from sparsesplat.engine.datasets.splits import dtu_split
from sparsesplat.engine.errors import CameraError, SceneError, reraise_as
from sparsesplat.engine.images import image_size, list_images
from sparsesplat.engine.scene import Scene

BLACK = (0.0, 0.0, 0.0)
image_folder = dtu_format.image_folder


def load_dtu(root: Path, views: int, downscale: int = 1) -> Scene:
    """Load a DTU scan with the RegNeRF split (train 25, 22, 28; the 25 test IDs), black
    background, object masks on every view."""
    npz_path = root / "cameras_sphere.npz"
    with reraise_as(SceneError):
        cams_npz = dtu_format.read_cameras(npz_path)
    files = list_images(image_folder(root))
    train_idx, test_idx = dtu_split(len(files), views, str(root))
    width, height = image_size(files[0])

    def camera(i: int) -> Camera:
        source = f"{npz_path} camera {i}"
        try:
            with reraise_as(SceneError):
                projection = dtu_format.projection(cams_npz, i, source)
            return camera_from_projection(projection, width, height, source)
        except CameraError as exc:
            raise SceneError(str(exc)) from exc

    def view(i: int):  # type: ignore[no-untyped-def]
        mask = dtu_format.mask_path(root, i, files[i])
        if mask is None:
            raise SceneError(f"{root / 'mask'}: no mask for camera {i} ({files[i].name})")
        return load_view(files[i].stem, files[i], camera(i), BLACK, downscale, mask_path=mask)

    train = [view(i) for i in train_idx]
    test = [view(i) for i in test_idx]
    dists = [float(torch.linalg.norm(v.camera.center)) for v in train + test]
    near, far = dtu_format.bounds(dists)
    return split_scene(
        root, "dtu", (train, test, BLACK), (near, far), UNIT_CUBE, (train_idx, test_idx)
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
