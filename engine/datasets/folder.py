"""The service's upload layout: a folder of images plus ``cameras.json`` (API schema)."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import numpy as np
import torch

from sparsesplat.engine.camera import Camera
from sparsesplat.engine.camera_convert import (
    check_intrinsics,
    w2c_from_opencv_c2w,
    w2c_from_opencv_w2c,
    w2c_from_opengl_c2w,
    w2c_from_opengl_w2c,
)
from sparsesplat.engine.datasets.common import covisible_box, load_view, look_at_bounds
from sparsesplat.engine.datasets.splits import check_view_count
from sparsesplat.engine.errors import CameraError, SceneError
from sparsesplat.engine.images import image_size, read_depth
from sparsesplat.engine.scene import Scene, View

CAMERAS_FILE = "cameras.json"
CONVERTERS = {
    ("opencv", "camera_to_world"): w2c_from_opencv_c2w,
    ("opencv", "world_to_camera"): w2c_from_opencv_w2c,
    ("opengl", "camera_to_world"): w2c_from_opengl_c2w,
    ("opengl", "world_to_camera"): w2c_from_opengl_w2c,
}
"""(convention, pose) -> converter to the internal world-to-camera."""


def _frame_camera(root: Path, frame: dict[str, Any], converter: Any, source: str) -> Camera:
    image = root / str(frame.get("image", ""))
    if "image" not in frame:
        raise SceneError(f"{source}: frame without 'image'")
    width, height = image_size(image)
    expect = (frame.get("width", width), frame.get("height", height))
    if expect != (width, height):
        raise SceneError(
            f"{image}: image is {width}x{height} but {CAMERAS_FILE} says {expect[0]}x{expect[1]}"
        )
    try:
        fx, fy = float(frame["fx"]), float(frame["fy"])
        cx, cy = float(frame.get("cx", width / 2.0)), float(frame.get("cy", height / 2.0))
    except KeyError as exc:
        raise SceneError(f"{source} ({frame['image']}): missing {exc.args[0]!r}") from exc
    except (TypeError, ValueError) as exc:
        raise SceneError(f"{source} ({frame['image']}): bad intrinsics ({exc})") from exc
    try:
        check_intrinsics(fx, fy, cx, cy, f"{source} ({frame['image']})")
        w2c = converter(frame.get("matrix"), f"{source} ({frame['image']})")
    except CameraError as exc:
        raise SceneError(str(exc)) from exc
    return Camera(w2c, fx, fy, cx, cy, width, height)


def load_folder(root: Path, views: int | None = None, downscale: int = 1) -> Scene:
    """Load an upload folder. Frames marked ``split: test`` are held out; of the training
    frames, ``views`` (default all) are taken evenly in file order. User depth maps are
    attached to their views as ``View.depth`` (divided by the optional ``depth_scale``, per
    frame or top level, e.g. 1000 for millimetre PNGs; 0 = no depth)."""
    path = root / CAMERAS_FILE
    if not path.is_file():
        raise SceneError(f"{path}: file not found")
    try:
        meta = json.loads(path.read_text())
    except (OSError, ValueError) as exc:
        raise SceneError(f"{path}: cannot parse JSON ({exc})") from exc
    if not isinstance(meta, dict) or not isinstance(meta.get("frames"), list):
        raise SceneError(f"{path}: expected an object with a 'frames' list")
    key = (meta.get("convention", "opencv"), meta.get("pose", "camera_to_world"))
    if key not in CONVERTERS:
        raise SceneError(
            f"{path}: unknown convention/pose {key}; expected convention opencv|opengl and "
            "pose camera_to_world|world_to_camera"
        )
    frames = meta["frames"]
    splits = [str(f.get("split", "train")) for f in frames]
    bad = [s for s in splits if s not in ("train", "test")]
    if bad:
        raise SceneError(f"{path}: split must be 'train' or 'test', got {bad[0]!r}")
    pool = [i for i, s in enumerate(splits) if s == "train"]
    test_idx = [i for i, s in enumerate(splits) if s == "test"]
    count = len(pool) if views is None else views
    check_view_count(count, len(pool), str(path))
    train_idx = [pool[round(float(k))] for k in np.linspace(0, len(pool) - 1, count)]
    cameras = {
        i: _frame_camera(root, frames[i], CONVERTERS[key], str(path)) for i in train_idx + test_idx
    }

    def view(i: int) -> View:
        frame = frames[i]
        depth = depth_path = None
        if frame.get("depth"):
            depth_path = root / str(frame["depth"])
            depth = read_depth(depth_path)
            if not np.all(np.isfinite(depth)):
                raise SceneError(f"{depth_path}: depth contains NaN or inf")
            # Integer PNG depth (e.g. millimetres) -> scene units: divide by depth_scale.
            scale = frame.get("depth_scale", meta.get("depth_scale", 1.0))
            try:
                scale = float(scale)
            except (TypeError, ValueError) as exc:
                raise SceneError(f"{path}: depth_scale {scale!r} is not a number") from exc
            if not np.isfinite(scale) or scale <= 0:
                raise SceneError(f"{path}: depth_scale must be positive, got {scale}")
            depth = depth / scale
        image = root / str(frame["image"])
        return load_view(
            image.stem, image, cameras[i], BLACK, downscale, depth=depth, depth_source=depth_path
        )

    train = [view(i) for i in train_idx]
    near, far = look_at_bounds([cameras[i] for i in train_idx])
    depths = [v.depth[v.depth > 0] for v in train if v.depth is not None]
    if depths and sum(d.numel() for d in depths) > 0:
        valid = torch.cat(depths)
        near, far = float(valid.min()) * 0.8, float(valid.max()) * 1.25
    box = covisible_box([cameras[i] for i in train_idx], [near] * count, [far] * count)
    return Scene(
        name=root.name,
        format="folder",
        train=train,
        test=[view(i) for i in test_idx],
        background=torch.tensor(BLACK),
        near=near,
        far=far,
        init_box=box,
        train_indices=train_idx,
        test_indices=test_idx,
    )


BLACK = (0.0, 0.0, 0.0)
