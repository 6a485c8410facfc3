"""LLFF scenes: ``poses_bounds.npy`` plus an ``images_N`` folder."""

from __future__ import annotations

from pathlib import Path

from sparsesplat.api.scenes import llff as llff_format
from sparsesplat.engine.camera_convert import cameras_from_llff
from sparsesplat.engine.camera_path import spiral_cameras
from sparsesplat.engine.datasets.common import covisible_box, load_view, split_scene
from sparsesplat.engine.datasets.splits import llff_split
from sparsesplat.engine.errors import CameraError, SceneError, reraise_as
from sparsesplat.engine.images import image_size, list_images
from sparsesplat.engine.scene import Scene

IMAGE_DIRS = llff_format.IMAGE_DIRS
find_image_dir = reraise_as(SceneError)(llff_format.find_image_dir)


def load_llff(root: Path, views: int, downscale: int = 1) -> Scene:
    """Load an LLFF scene with the RegNeRF/DNGaussian split; poses stay in COLMAP units."""
    pb_path = root / "poses_bounds.npy"
    with reraise_as(SceneError):
        pb = llff_format.read_poses_bounds(pb_path)
    image_dir = find_image_dir(root)
    files = list_images(image_dir)  # lexicographic, the row order of poses_bounds
    if len(files) != len(pb):
        raise SceneError(f"{pb_path}: {len(pb)} poses but {len(files)} images in {image_dir}")
    width, height = image_size(files[0])
    try:
        cameras, bounds = cameras_from_llff(pb, (height, width), str(pb_path))
    except CameraError as exc:
        raise SceneError(str(exc)) from exc
    train_idx, test_idx = llff_split(len(files), views, str(root))
    background = (0.0, 0.0, 0.0)

    def view(i: int):  # type: ignore[no-untyped-def]
        return load_view(files[i].stem, files[i], cameras[i], background, downscale)

    train = [view(i) for i in train_idx]
    test = [view(i) for i in test_idx]
    box = covisible_box(
        [cameras[i] for i in train_idx],
        [float(bounds[i, 0]) for i in train_idx],
        [float(bounds[i, 1]) for i in train_idx],
    )
    near, far = float(bounds[:, 0].min()), float(bounds[:, 1].max())
    path = []
    if train:
        try:
            # Intrinsics of the first training view: already scaled by any downscale.
            poses = [c.camera_to_world for c in cameras]
            path = spiral_cameras(poses, near, far, train[0].camera)
        except CameraError:
            pass  # a rig without an average viewing direction has no spiral; not fatal
    return split_scene(
        root,
        "llff",
        (train, test, background),
        (near, far),
        box,
        (train_idx, test_idx),
        render_path=path,
    )
