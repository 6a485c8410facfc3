"""Small upload-folder scenes for the CLI tests: an object rendered from a few cameras and
written as RGBA PNGs with ``cameras.json`` in any convention, at any unit."""

from __future__ import annotations

import json
import math
from pathlib import Path
from typing import Any

import numpy as np
import torch
from PIL import Image

from sparsesplat.engine.camera import Camera
from sparsesplat.engine.camera_convert import opengl_c2w_from_w2c, rigid_inverse
from sparsesplat.engine.raster import rasterize
from sparsesplat.engine.synthetic import look_at

FLIP_YZ = np.diag([1.0, -1.0, -1.0, 1.0])


def object_cameras(count: int, size: int, scale: float = 1.0) -> list[Camera]:
    """``count`` cameras on a ring around the origin at distance 4 * scale, looking inward."""
    cams = []
    for k in range(count):
        a = 2.0 * math.pi * k / count
        eye = torch.tensor([4.0 * math.sin(a), -1.0 + 0.5 * (k % 2), -4.0 * math.cos(a)]) * scale
        f = 1.1 * size
        cams.append(Camera(look_at(eye, torch.zeros(3)), f, f, size / 2, size / 2, size, size))
    return cams


def object_blob(seed: int = 0, n: int = 80, scale: float = 1.0) -> tuple[torch.Tensor, ...]:
    """A random blob of opaque coloured Gaussians in a unit-ish ball (times ``scale``)."""
    g = torch.Generator().manual_seed(seed)
    means = (torch.rand(n, 3, generator=g) - 0.5) * 1.6 * scale
    log_scales = torch.full((n, 3), math.log(0.18 * scale))
    quats = torch.nn.functional.normalize(torch.randn(n, 4, generator=g), dim=1)
    opacity = torch.full((n,), 3.0)
    colors = 0.1 + 0.8 * torch.rand(n, 3, generator=g)
    return means, log_scales, quats, opacity, colors


def frame_matrix(cam: Camera, convention: str, pose: str) -> list[list[float]]:
    """The camera's pose as cameras.json stores it in ``convention`` / ``pose``."""
    w2c = cam.world_to_camera.double().numpy()
    if convention == "opencv":
        m = w2c if pose == "world_to_camera" else rigid_inverse(w2c)
    else:
        c2w_gl = opengl_c2w_from_w2c(cam.world_to_camera.double())
        m = c2w_gl if pose == "camera_to_world" else rigid_inverse(c2w_gl)
    return np.asarray(m).tolist()


def write_object_scene(
    root: Path,
    convention: str = "opengl",
    pose: str = "camera_to_world",
    count: int = 6,
    test: int = 2,
    size: int = 48,
    scale: float = 1.0,
    seed: int = 0,
    alpha: bool = True,
    edit: Any = None,
) -> Path:
    """Render the blob from ``count`` ring cameras (the last ``test`` held out) and write the
    upload folder: RGBA PNGs (straight alpha, transparent where nothing is) or RGB on black,
    plus cameras.json. ``edit(meta)`` may change the JSON before it is written."""
    root.mkdir(parents=True, exist_ok=True)
    blob = object_blob(seed, scale=scale)
    frames = []
    for i, cam in enumerate(object_cameras(count, size, scale)):
        with torch.no_grad():
            out = rasterize(*blob, cam, torch.zeros(3), near=0.01 * scale, backend="reference")
        a = out.alpha[0].clamp(0, 1).numpy()
        premult = out.image.permute(1, 2, 0).clamp(0, 1).numpy()
        rgb = np.where(a[..., None] > 1e-4, premult / np.maximum(a, 1e-4)[..., None], 0.0)
        if alpha:
            rgba = np.concatenate([np.clip(rgb, 0, 1), a[..., None]], axis=-1)
            data = (rgba * 255 + 0.5).astype(np.uint8)
            Image.fromarray(data, "RGBA").save(root / f"r_{i}.png")
        else:
            data = (np.clip(premult, 0, 1) * 255 + 0.5).astype(np.uint8)
            Image.fromarray(data, "RGB").save(root / f"r_{i}.png")
        frames.append(
            {
                "image": f"r_{i}.png",
                "matrix": frame_matrix(cam, convention, pose),
                "fx": cam.fx,
                "fy": cam.fy,
                "cx": cam.cx,
                "cy": cam.cy,
                "width": size,
                "height": size,
                "split": "test" if i >= count - test else "train",
            }
        )
    meta: dict[str, Any] = {"convention": convention, "pose": pose, "frames": frames}
    if edit is not None:
        edit(meta)
    (root / "cameras.json").write_text(json.dumps(meta, indent=1))
    return root


def shrink_images(root: Path, which: str) -> None:
    """Replace the images of a written scene by 1x1 pixels (``which``: "all" or "test", the
    held-out views only), with matching intrinsics in its cameras.json."""
    meta = json.loads((root / "cameras.json").read_text())
    for f in meta["frames"]:
        if which == "all" or f["split"] == "test":
            Image.new("RGBA", (1, 1)).save(root / f["image"])
            f.update(width=1, height=1, cx=0.5, cy=0.5)
    (root / "cameras.json").write_text(json.dumps(meta))
