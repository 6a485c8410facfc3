"""A folder scene's ``cameras.json`` with its training poses as trained.

When the training poses were refined (``poses.enabled``), the model lives in the frame of the
refined cameras: its first training camera keeps its pose, the others moved by a fraction of a
degree. Rendering a training view through the pose the upload gave would show the model
slightly off the photo, so what the service calls "the cameras it was trained with", and what
``sparsesplat train`` writes beside its model, is the upload's file with the training frames'
matrices replaced, in the file's own convention and pose direction. Everything else (images,
intrinsics, held-out frames, bounds) is the upload's.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

from sparsesplat.api.cameras import CamerasFile
from sparsesplat.engine.camera import Camera
from sparsesplat.engine.camera_convert import file_pose_from_w2c
from sparsesplat.engine.errors import SceneError
from sparsesplat.engine.scene import Scene


def trained_cameras(
    document: CamerasFile, train_indices: list[int], cameras: list[Camera]
) -> dict[str, Any]:
    """``document`` (the scene's ``cameras.json``) as JSON data with frame
    ``train_indices[k]``'s matrix replaced by ``cameras[k]``'s pose; its
    ``rotation_std_deg`` is dropped there (the refined pose is no longer the estimate it
    described). Raises :class:`SceneError` when the two lists differ in length, an index is
    not a frame, or a pose is not finite: a cameras file that does not match its model is
    not written."""
    if len(train_indices) != len(cameras):
        raise SceneError(f"{len(cameras)} trained cameras for {len(train_indices)} training frames")
    data = document.model_dump(mode="json", exclude_none=True)
    frames = data["frames"]
    for index, camera in zip(train_indices, cameras, strict=True):
        if not 0 <= index < len(frames):
            raise SceneError(f"training frame {index} is not in the cameras file")
        w2c = camera.world_to_camera.detach().double().cpu()
        if not bool(w2c.isfinite().all()):
            raise SceneError(f"the trained pose of frame {frames[index]['image']} is not finite")
        frames[index]["matrix"] = file_pose_from_w2c(w2c, document.convention, document.pose)
        frames[index].pop("rotation_std_deg", None)
    return data


TRAINED_CAMERAS_FILE = "trained_cameras.json"
"""What ``sparsesplat train`` writes beside its model when it refined the training poses."""


def folder_trained_cameras(folder: Path, scene: Scene, cameras: list[Camera]) -> dict[str, Any]:
    """:func:`trained_cameras` of the folder scene ``scene`` loaded from ``folder`` (its
    ``cameras.json`` read again, its training frames by ``scene.train_indices``)."""
    from sparsesplat.engine.datasets.folder import CAMERAS_FILE, read_cameras_file

    if scene.format != "folder":
        raise SceneError(f"trained cameras are written for folder scenes, not {scene.format}")
    return trained_cameras(read_cameras_file(folder / CAMERAS_FILE), scene.train_indices, cameras)
