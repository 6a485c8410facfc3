"""Upload folders made from the shared scenes, at smoke scale (small images, few views)."""

from __future__ import annotations

import json
import math
from pathlib import Path
from typing import Any

from PIL import Image

SHARED = Path(__file__).resolve().parents[2].parent / "shared" / "data"
MIC = SHARED / "nerf_synthetic" / "mic"
TRAIN_IDS = (26, 86, 2)
"""The first three of DNGaussian's Blender training views."""
TEST_IDS = (0, 8)
"""Two held-out views of the test split."""


def blender_frames(size: int) -> list[dict[str, Any]]:
    """Frames (OpenGL camera-to-world, as Blender writes them) for the smoke upload."""
    frames = []
    for split, ids, source in (("train", TRAIN_IDS, "train"), ("test", TEST_IDS, "test")):
        meta = json.loads((MIC / f"transforms_{source}.json").read_text())
        focal = 0.5 * size / math.tan(0.5 * meta["camera_angle_x"])
        for i in ids:
            frame = meta["frames"][i]
            frames.append(
                {
                    "image": f"{split}_{i}.png",
                    "source": str(MIC / (frame["file_path"].removeprefix("./") + ".png")),
                    "matrix": frame["transform_matrix"],
                    "fx": focal,
                    "fy": focal,
                    "cx": size / 2,
                    "cy": size / 2,
                    "split": split,
                }
            )
    return frames


def write_mic_upload(folder: Path, size: int = 100) -> Path:
    """``folder`` with cameras.json and RGBA PNGs of mic at ``size`` x ``size`` pixels."""
    folder.mkdir(parents=True, exist_ok=True)
    frames = blender_frames(size)
    for frame in frames:
        with Image.open(frame.pop("source")) as image:
            image.resize((size, size), Image.Resampling.LANCZOS).save(folder / frame["image"])
    cameras = {"convention": "opengl", "pose": "camera_to_world", "frames": frames}
    (folder / "cameras.json").write_text(json.dumps(cameras, indent=1))
    return folder


def turn_held_out_cameras_around(folder: Path) -> Path:
    """Rewrite the held-out frames of ``folder``'s cameras.json in the OpenCV convention while
    the file still says OpenGL (as when held-out poses come from another tool): read as the file
    says, each held-out camera looks away from the scene. The upload's pose checks look at the
    training cameras and pass it; only training can find that those views render nothing."""
    path = folder / "cameras.json"
    cameras = json.loads(path.read_text())
    assert cameras["convention"] == "opengl", cameras["convention"]
    for frame in cameras["frames"]:
        if frame.get("split") == "test":
            # OpenGL -> OpenCV camera-to-world: negate the camera's y and z axes (columns 1, 2).
            frame["matrix"] = [[r[0], -r[1], -r[2], r[3]] for r in frame["matrix"]]
    path.write_text(json.dumps(cameras, indent=1))
    return folder
