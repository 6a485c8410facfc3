"""NeRF-synthetic (Blender) scenes: ``transforms_{train,test}.json`` with RGBA frames."""

from __future__ import annotations

from pathlib import Path
from typing import Any

from sparsesplat.api.scenes import transforms as transforms_format
from sparsesplat.engine.camera import Camera
from sparsesplat.engine.camera_convert import camera_from_transforms_frame
from sparsesplat.engine.datasets.common import load_view, split_scene
from sparsesplat.engine.datasets.splits import blender_split
from sparsesplat.engine.errors import CameraError, SceneError, reraise_as
from sparsesplat.engine.images import image_size
from sparsesplat.engine.scene import Scene, View

WHITE = (1.0, 1.0, 1.0)


read_transforms = reraise_as(SceneError)(transforms_format.read_transforms)
frame_image_path = reraise_as(SceneError)(transforms_format.frame_image_path)


def frame_camera(root: Path, meta: dict[str, Any], frame: dict[str, Any], source: str) -> Camera:
    """Camera of one transforms.json frame (OpenGL camera-to-world pose)."""
    path = frame_image_path(root, frame, source)
    width, height = image_size(path)
    try:
        return camera_from_transforms_frame(
            meta, frame, width, height, f"{source} {frame['file_path']}"
        )
    except CameraError as exc:
        raise SceneError(str(exc)) from exc


def load_frames(
    root: Path, json_name: str, indices: list[int], downscale: int, background: tuple
) -> list[View]:
    """Load the listed frames of one transforms file."""
    path = root / json_name
    meta = read_transforms(path)
    views = []
    for i in indices:
        frame = meta["frames"][i]
        cam = frame_camera(root, meta, frame, str(path))
        image_path = frame_image_path(root, frame, str(path))
        views.append(load_view(image_path.stem, image_path, cam, background, downscale))
    return views


def load_blender(root: Path, views: int, downscale: int = 1) -> Scene:
    """Load a NeRF-synthetic scene: train frames 26, 86, 2, 55, 75, 93, 16, 73 (first
    ``views``), test every 8th frame of the test split, RGBA composited on white."""
    train_meta = read_transforms(root / "transforms_train.json")
    test_meta = read_transforms(root / "transforms_test.json")
    train_idx, test_idx = blender_split(
        len(train_meta["frames"]), len(test_meta["frames"]), views, str(root)
    )
    train = load_frames(root, "transforms_train.json", train_idx, downscale, WHITE)
    test = load_frames(root, "transforms_test.json", test_idx, downscale, WHITE)
    return split_scene(
        root, "blender", (train, test, WHITE),
        (transforms_format.BLENDER_NEAR, transforms_format.BLENDER_FAR),
        transforms_format.UNIT_CUBE, (train_idx, test_idx),
    )  # fmt: skip
