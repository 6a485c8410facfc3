"""The Blender ``mic`` scene converted by hand to the upload format, as issue #11 did: once as
OpenGL camera-to-world, once as OpenCV world-to-camera. Same poses as the Blender loader,
same training figures, white background."""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest
import torch
from PIL import Image

from sparsesplat.engine.datasets import load_scene
from sparsesplat.engine.train import Trainer
from sparsesplat.engine.train.config.presets import choose_preset
from tests.engine.datasets.synthetic import smoke_preset

FLIP_YZ = np.diag([1.0, -1.0, -1.0, 1.0])
SIZE = 100
TRAIN = (26, 86, 2)
TEST = (0, 8)


def _convert(mic: Path, out: Path, convention: str) -> Path:
    """Frames TRAIN of transforms_train.json and TEST of transforms_test.json, at SIZE px."""
    out.mkdir(parents=True)
    frames = []
    for split, source, picks in (("train", "train", TRAIN), ("test", "test", TEST)):
        meta = json.loads((mic / f"transforms_{source}.json").read_text())
        for i in picks:
            frame = meta["frames"][i]
            name = f"{source}_{i}.png"
            with Image.open(mic / (frame["file_path"] + ".png")) as img:
                img.convert("RGBA").resize((SIZE, SIZE), Image.Resampling.BOX).save(out / name)
            focal = 0.5 * SIZE / math.tan(0.5 * meta["camera_angle_x"])
            c2w_gl = np.array(frame["transform_matrix"], dtype=np.float64)
            # OpenCV world-to-camera: flip the camera's y/z axes, then invert.
            matrix = c2w_gl if convention == "opengl" else np.linalg.inv(c2w_gl @ FLIP_YZ)
            frames.append(
                {
                    "image": name,
                    "matrix": matrix.tolist(),
                    "fx": focal,
                    "fy": focal,
                    "cx": SIZE / 2,
                    "cy": SIZE / 2,
                    "split": split,
                }
            )
    pose = "camera_to_world" if convention == "opengl" else "world_to_camera"
    cameras = {"convention": convention, "pose": pose, "frames": frames}
    (out / "cameras.json").write_text(json.dumps(cameras))
    return out


@pytest.mark.shared_data
def test_mic_converted_both_ways_trains_identically(shared_data: Path, tmp_path: Path) -> None:
    mic = shared_data / "nerf_synthetic" / "mic"
    gl = load_scene(_convert(mic, tmp_path / "gl", "opengl"))
    cv = load_scene(_convert(mic, tmp_path / "cv", "opencv"))
    blender = load_scene(mic, views=8)
    by_name = {v.name: v for v in blender.train}
    for a, b in zip(gl.train, cv.train, strict=True):
        assert torch.allclose(a.camera.world_to_camera, b.camera.world_to_camera, atol=1e-5)
        ref = by_name[f"r_{a.name.split('_')[1]}"].camera.world_to_camera
        assert torch.allclose(a.camera.world_to_camera, ref, atol=1e-5), a.name
        assert torch.equal(a.image, b.image)
    assert gl.background.tolist() == [1.0, 1.0, 1.0] == cv.background.tolist()
    assert choose_preset(gl)[0] == "object"
    corner = gl.train[0].image[0, 0]
    assert torch.allclose(corner, torch.ones(3)), "transparent pixels composited on white"
    cfg = smoke_preset("object", 15, seed=0, init_points=500, threads=1)
    torch.set_num_threads(1)  # bit-identical runs (the fixture restores the thread count)
    a = Trainer(gl, cfg).run().metrics
    b = Trainer(cv, cfg).run().metrics
    assert a["psnr"] == pytest.approx(b["psnr"], abs=1e-4), (a, b)
    assert a["background_psnr"] == pytest.approx(b["background_psnr"], abs=1e-9)
    assert math.isfinite(a["psnr"]) and a["n_gaussians"] == b["n_gaussians"]
