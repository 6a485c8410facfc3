"""The service's upload layout: a folder of images plus ``cameras.json``.

``cameras.json`` is validated by the wire schema itself (:class:`sparsesplat.api.cameras.
CamerasFile`), so the folder loader and the HTTP service accept and refuse exactly the same
files, with the same messages (docs/cameras.md)."""

from __future__ import annotations

import json
import logging
from pathlib import Path

import numpy as np
import torch
from pydantic import ValidationError

from sparsesplat.api.cameras import (
    CameraFrame,
    CamerasFile,
    Split,
    describe_validation_error,
    to_world_to_camera_opencv,
)
from sparsesplat.api.scenes.splits import evenly
from sparsesplat.engine.camera import Camera
from sparsesplat.engine.datasets.common import (
    BLACK,
    CommonView,
    check_camera_positions,
    check_image_size,
    check_overlap,
    common_view,
    covisible_box,
    load_view,
    look_at_bounds,
    on_default_background,
    split_scene,
)
from sparsesplat.engine.datasets.splits import check_view_count
from sparsesplat.engine.errors import SceneError
from sparsesplat.engine.images import image_size, read_depth
from sparsesplat.engine.scene import Scene, View
from sparsesplat.engine.sfm.points import read_sparse_points

log = logging.getLogger(__name__)

CAMERAS_FILE = "cameras.json"
"""Name of the cameras file inside an upload folder."""


def read_cameras_file(path: Path) -> CamerasFile:
    """Parse and validate ``cameras.json``; SceneError naming the file and every problem."""
    if not path.is_file():
        raise SceneError(f"{path}: file not found")
    try:
        data = json.loads(path.read_text())
    except (OSError, UnicodeDecodeError, ValueError) as exc:
        raise SceneError(f"{path}: cannot parse JSON ({exc})") from exc
    try:
        return CamerasFile.model_validate(data)
    except ValidationError as exc:
        raise SceneError(f"{path}: {describe_validation_error(exc, data)}") from exc


def _frame_camera(root: Path, frame: CameraFrame, meta: CamerasFile, source: str) -> Camera:
    """The engine camera of one validated frame (image size read from the file header)."""
    image = root / frame.image
    width, height = image_size(image)
    expect = (frame.width or width, frame.height or height)
    if expect != (width, height):
        raise SceneError(
            f"{image}: image is {width}x{height} but {CAMERAS_FILE} says {expect[0]}x{expect[1]}"
        )
    check_image_size(width, height, str(image))
    w2c = to_world_to_camera_opencv(frame.matrix, meta.convention, meta.pose)
    return Camera(
        torch.tensor(w2c, dtype=torch.float64).float(),
        frame.fx,
        frame.fy,
        frame.cx,
        frame.cy,
        width,
        height,
    )


def _user_depth(root: Path, frame: CameraFrame, meta: CamerasFile) -> tuple[np.ndarray, Path]:
    """A frame's depth map in scene units (integer PNGs divided by ``depth_scale``)."""
    assert frame.depth is not None
    path = root / frame.depth
    depth = read_depth(path)
    if not np.all(np.isfinite(depth)):
        raise SceneError(f"{path}: depth contains NaN or inf")
    scale = frame.depth_scale if frame.depth_scale is not None else meta.depth_scale
    return depth / scale, path


def _scene_bounds(
    meta: CamerasFile,
    frames: list[CameraFrame],
    train: list[View],
    train_cams: list[Camera],
    source: str,
    seen: CommonView | None = None,
) -> tuple[float, float]:
    """The scene's near/far: the file's, else the frames' own (nearest near, farthest far),
    else the user depth maps' range with a margin, else the depth range of ``seen`` (what all
    training cameras see), else where the optical axes meet."""
    frame_near = [f.near for f in frames if f.near is not None]
    frame_far = [f.far for f in frames if f.far is not None]
    near = meta.near or (min(frame_near) if frame_near else None)
    far = meta.far or (max(frame_far) if frame_far else None)
    if near is None or far is None:  # estimate only what was not given
        guess_near, guess_far = look_at_bounds(train_cams)
        if seen is not None:  # an object seen from around it: the depths of what all see
            guess_near, guess_far = seen.near, seen.far
        depths = [v.depth[v.depth > 0] for v in train if v.depth is not None]
        if depths and sum(d.numel() for d in depths) > 0:
            valid = torch.cat(depths)
            guess_near, guess_far = float(valid.min()) * 0.8, float(valid.max()) * 1.25
        near, far = near or guess_near, far or guess_far
    if not near < far:
        raise SceneError(f"{source}: near {near:g} is not below far {far:g}: check near/far")
    return near, far


def _view_bounds(
    frames: list[CameraFrame], near: float, far: float, source: str
) -> tuple[list[float], list[float]]:
    """Each frame's near/far, the scene's where the frame gives none."""
    nears = [f.near or near for f in frames]
    fars = [f.far or far for f in frames]
    for frame, lo, hi in zip(frames, nears, fars, strict=True):
        if not lo < hi:
            raise SceneError(
                f"{source}: frame {frame.image!r}: near {lo:g} is not below far {hi:g}"
            )
    return nears, fars


def load_folder(root: Path, views: int | None = None, downscale: int = 1) -> Scene:
    """Load an upload folder. Frames marked ``split: test`` are held out; of the training
    frames, ``views`` (default all) are taken evenly in file order. User depth maps are
    attached to their views as ``View.depth`` (divided by the optional ``depth_scale``, per
    frame or top level, e.g. 1000 for millimetre PNGs), object masks as ``View.mask`` (a
    held-out view with one is scored on the object, the DTU protocol). The scene's near/far
    and init box are the file's ``near``/``far``/``init_box`` when it gives them (per-frame
    bounds shape the box), else estimated: for an object photographed from around it, the
    region all training cameras see and its depth range (:func:`common_view`), else the region
    two cameras see between the look-at bounds (:func:`_scene_bounds`, :func:`covisible_box`).

    Images with an alpha channel are composited on white (the scene background), without
    alpha the background is black; the trainer re-composites on its configured background."""
    path = root / CAMERAS_FILE
    meta = read_cameras_file(path)
    frames = meta.frames
    pool = [i for i, f in enumerate(frames) if f.split == Split.train]
    test_idx = [i for i, f in enumerate(frames) if f.split == Split.test]
    count = len(pool) if views is None else views
    check_view_count(count, len(pool), str(path))
    train_idx = evenly(pool, count)
    cameras = {i: _frame_camera(root, frames[i], meta, str(path)) for i in train_idx + test_idx}
    train_cams = [cameras[i] for i in train_idx]
    train_names = [frames[i].image for i in train_idx]
    all_idx = train_idx + test_idx
    check_camera_positions(
        [cameras[i] for i in all_idx], [frames[i].image for i in all_idx], str(path)
    )

    def view(i: int, background: tuple[float, ...]) -> View:
        frame = frames[i]
        depth = depth_path = None
        if frame.depth:
            depth, depth_path = _user_depth(root, frame, meta)
        image = root / frame.image
        return load_view(
            image.stem,
            image,
            cameras[i],
            background,
            downscale,
            mask_path=root / frame.mask if frame.mask else None,
            depth=depth,
            depth_source=depth_path,
        )

    train, test, background = on_default_background(
        [view(i, BLACK) for i in train_idx], [view(i, BLACK) for i in test_idx], BLACK
    )
    given: list[object] = [meta.near, meta.far, meta.init_box]
    given += [v for f in frames for v in (f.near, f.far, f.depth)]
    # No bounds at all (the documented recipe for Blender-like uploads): frame the scene by
    # what every training camera sees rather than by the wide look-at guess.
    seen = common_view(train_cams) if all(v is None for v in given) else None
    near, far = _scene_bounds(
        meta, [frames[i] for i in all_idx], train, train_cams, str(path), seen
    )
    train_near, train_far = _view_bounds([frames[i] for i in train_idx], near, far, str(path))
    alone = check_overlap(train_cams, train_names, near, far, str(path))
    if alone:
        log.warning(
            "%s: training view(s) %s share nothing with the other cameras: check their matrices",
            path,
            ", ".join(alone),
        )
    box = meta.init_box or (
        seen.box if seen is not None else covisible_box(train_cams, train_near, train_far)
    )
    return split_scene(
        root, "folder", (train, test, background), (near, far), box, (train_idx, test_idx),
        sparse_points=read_sparse_points(root),
        pose_std_deg=_pose_std_deg([frames[i] for i in train_idx]),
    )  # fmt: skip


def _pose_std_deg(frames: list[CameraFrame]) -> float | None:
    """The largest ``rotation_std_deg`` of ``frames`` (the training frames); None when none
    gives one."""
    given = [f.rotation_std_deg for f in frames if f.rotation_std_deg is not None]
    return max(given) if given else None
