"""instant-ngp / nerfstudio scenes: one ``transforms.json`` (fl_x, fl_y, cx, cy, w, h)."""

from __future__ import annotations

from pathlib import Path

from sparsesplat.api.scenes import transforms as transforms_format
from sparsesplat.engine.datasets.blender import frame_camera, frame_image_path, read_transforms
from sparsesplat.engine.datasets.common import (
    covisible_box,
    load_view,
    look_at_bounds,
    on_default_background,
    split_scene,
)
from sparsesplat.engine.datasets.splits import llff_split
from sparsesplat.engine.errors import SceneError, reraise_as
from sparsesplat.engine.scene import Scene

BLACK = (0.0, 0.0, 0.0)


def load_ngp(root: Path, views: int, downscale: int = 1) -> Scene:
    """Load an instant-ngp scene with the LLFF-style split over frames sorted by file path.
    Frames with alpha are composited on white (the scene background), others stay as shot.

    Lens distortion (OpenCV k1, k2, p1, p2) is removed: images are resampled to the ideal
    pinhole camera with the same intrinsics (black where the lens saw nothing)."""
    path = root / "transforms.json"
    meta = read_transforms(path)
    frames = sorted(meta["frames"], key=lambda f: str(f.get("file_path")))
    cameras = [frame_camera(root, meta, f, str(path)) for f in frames]
    train_idx, test_idx = llff_split(len(frames), views, str(root))

    def view(i: int):  # type: ignore[no-untyped-def]
        image_path = frame_image_path(root, frames[i], str(path))
        with reraise_as(SceneError):
            coeffs = transforms_format.distortion(meta, frames[i], str(path))
        return load_view(
            image_path.stem, image_path, cameras[i], BLACK, downscale, distortion=coeffs
        )

    near, far = look_at_bounds(cameras)
    train_cams = [cameras[i] for i in train_idx]
    box = covisible_box(train_cams, [near] * len(train_cams), [far] * len(train_cams))
    # RGBA frames (nerfstudio/instant-ngp cut-outs) go on white, like every alpha capture.
    train, test, background = on_default_background(
        [view(i) for i in train_idx], [view(i) for i in test_idx], BLACK
    )
    return split_scene(
        root, "ngp", (train, test, background), (near, far), box, (train_idx, test_idx)
    )
