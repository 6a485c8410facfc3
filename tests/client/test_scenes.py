"""The torch-free scene reader agrees with the engine's loaders: same training and held-out
views, same cameras; the camera helpers do what their names say."""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest

from sparsesplat.api.cameras import PinholeCamera, to_world_to_camera_opencv
from sparsesplat.client import InvalidInput, cameras, from_images, media, read_scene
from sparsesplat.client import scenes as client_scenes

SHARED = Path(__file__).resolve().parents[2].parent / "shared" / "data"
SCENES = {
    "llff": SHARED / "nerf_llff_data" / "beer_can",
    "blender": SHARED / "nerf_synthetic" / "mic",
    "dtu": SHARED / "dtu" / "dtu_scan24",
    "ngp": SHARED / "instant_ngp" / "fox",
}


def test_split_data_matches_the_engine() -> None:
    from sparsesplat.engine.datasets import PAPER_VIEWS, splits

    assert client_scenes.PAPER_VIEWS == PAPER_VIEWS
    assert client_scenes.DTU_TRAIN_ORDER == splits.DTU_TRAIN_ORDER
    assert client_scenes.DTU_TEST == splits.DTU_TEST
    assert client_scenes.BLENDER_TRAIN_ORDER == splits.BLENDER_TRAIN_ORDER
    assert client_scenes.BLENDER_TEST_STRIDE == splits.BLENDER_TEST_STRIDE
    assert client_scenes.LLFF_HOLDOUT == splits.LLFF_HOLDOUT
    for count in range(3, 120):
        for views in range(2, 10):
            pool = count - len(range(0, count, 8))
            if views <= pool:
                assert client_scenes.llff_split(count, views) == splits.llff_split(count, views)
    assert client_scenes.dtu_split(49, 3) == splits.dtu_split(49, 3)
    assert client_scenes.blender_split(100, 200, 8) == splits.blender_split(100, 200, 8)


def _w2c(upload: client_scenes.Upload, name: str) -> tuple[np.ndarray, PinholeCamera]:
    cam = upload.camera(name)
    return np.array(to_world_to_camera_opencv(cam.matrix, cam.convention, cam.pose)), cam


@pytest.mark.shared_data
@pytest.mark.parametrize("fmt", sorted(SCENES))
def test_folder_reader_matches_the_engine(fmt: str) -> None:
    from sparsesplat.engine.datasets import load_scene

    root = SCENES[fmt]
    upload = read_scene(root, test_views="all")
    scene = load_scene(root)
    assert upload.source.endswith(f"({fmt})")
    assert upload.train_indices == scene.train_indices
    assert upload.test_indices == scene.test_indices
    assert upload.preset == {"llff": "llff", "blender": "blender", "dtu": "dtu"}.get(fmt)
    names = upload.frame_names("train") + upload.frame_names("test")
    for name, view in zip(names, scene.train + scene.test, strict=True):
        w2c, cam = _w2c(upload, name)
        ref = view.camera
        np.testing.assert_allclose(w2c, ref.world_to_camera.double().numpy(), atol=2e-4)
        got = (cam.fx, cam.fy, cam.cx, cam.cy, cam.width, cam.height)
        want = (ref.fx, ref.fy, ref.cx, ref.cy, ref.width, ref.height)
        np.testing.assert_allclose(got, want, rtol=1e-5)
    if fmt == "ngp":  # distorted lens: our undistorted image matches the engine's
        image = media.decode_array(upload.images[names[0]]).astype(np.float32) / 255
        ref_image = scene.train[0].image.numpy()
        if ref_image.shape[0] == 3:
            ref_image = ref_image.transpose(1, 2, 0)
        assert image.shape == ref_image.shape
        assert float(np.abs(image - ref_image).mean()) < 2 / 255


def _write_upload(upload: client_scenes.Upload, folder: Path) -> Path:
    """The upload as the service stores it: cameras.json beside the files it names."""
    folder.mkdir()
    (folder / "cameras.json").write_text(json.dumps(upload.cameras))
    for name, data in {**upload.images, **upload.masks}.items():
        (folder / name).write_bytes(data)
    return folder


@pytest.mark.shared_data
@pytest.mark.parametrize("fmt", ["llff", "blender", "dtu"])
def test_an_upload_keeps_the_format_s_depth_range_and_init_box(fmt: str, tmp_path: Path) -> None:
    """A scene sent to the service trains in the frame the engine's own loader gives it: same
    near/far (the priors' sweep range, the near cull) and the same random-init box. Without
    them an upload of DTU scan24 got near 0.53 / far 7.9 instead of 1.78 / 3.97."""
    from sparsesplat.engine.datasets import load_scene

    upload = read_scene(SCENES[fmt], test_views=2)
    folder = load_scene(_write_upload(upload, tmp_path / "upload"), format="folder")
    scene = load_scene(SCENES[fmt])
    # DTU's engine loader takes camera centres in float32 (|t| ~ 3): a few ulp, under 1e-5.
    assert folder.near == pytest.approx(scene.near, abs=1e-5)
    assert folder.far == pytest.approx(scene.far, abs=1e-5)
    np.testing.assert_allclose(folder.init_box, scene.init_box, rtol=1e-5, atol=1e-5)


@pytest.mark.shared_data
def test_views_test_views_and_downscale() -> None:
    upload = read_scene(SCENES["blender"], views=3, test_views=2, downscale=4)
    assert (upload.n_train, upload.n_test) == (3, 2)
    assert upload.train_indices == [26, 86, 2] and upload.test_indices == [0, 192]
    cam = upload.test_cameras()[0]
    full = read_scene(SCENES["blender"], views=3, test_views=2).test_cameras()[0]
    assert (cam.width, cam.height) == (100, 100)
    assert math.isclose(cam.fx, full.fx / 4) and math.isclose(cam.cx, full.cx / 4)
    assert media.image_size(upload.images[upload.frame_names("test")[0]]) == (100, 100)
    with pytest.raises(InvalidInput, match="at least 2 training views"):
        read_scene(SCENES["blender"], views=1)
    none = read_scene(SCENES["blender"], views=2, test_views=0)
    assert none.n_test == 0


def test_unknown_folder_is_refused(tmp_path: Path) -> None:
    with pytest.raises(InvalidInput, match="unknown scene format"):
        read_scene(tmp_path)
    with pytest.raises(InvalidInput, match="not found"):
        read_scene(tmp_path / "missing")


def test_from_images_accepts_arrays_and_mixed_conventions(tmp_path: Path) -> None:
    k = cameras.Intrinsics.from_fov(24, 16, 60)
    ring = cameras.orbit((0, 0, 0), 3.0, 3, intrinsics=k, arc_deg=90)
    # The same poses written in other conventions are converted to the first one's.
    gl = cameras.from_matrix(
        [[r[0], -r[1], -r[2], r[3]] for r in cameras.camera_to_world_opencv(ring[1])],
        convention="opengl", pose="camera_to_world", intrinsics=k,
    )  # fmt: skip
    images = [np.full((16, 24, 3), i * 60, np.uint8) for i in range(3)]
    path = tmp_path / "third.png"
    path.write_bytes(media.encode_png(images[2]))
    upload = from_images([images[0], images[1], path], [ring[0], gl, ring[2]])
    assert upload.n_train == 3 and "third.png" in upload.images
    w2c = [_w2c(upload, n)[0] for n in upload.frame_names("train")]
    for got, cam in zip(w2c, ring, strict=True):
        want = to_world_to_camera_opencv(cam.matrix, cam.convention, cam.pose)
        np.testing.assert_allclose(got, want, atol=1e-9)
    with pytest.raises(InvalidInput, match="16x24"):
        from_images([np.zeros((24, 16, 3), np.uint8)] * 3, ring)


def test_from_images_carries_bounds_and_refuses_reversed_ones() -> None:
    k = cameras.Intrinsics.from_fov(24, 16, 60)
    ring = cameras.orbit((0, 0, 0), 3.0, 3, intrinsics=k, arc_deg=90)
    images = [np.zeros((16, 24, 3), np.uint8)] * 3
    box = ((-1.0, -1.0, -1.0), (1.0, 1.0, 1.0))
    upload = from_images(images, ring, near=2.0, far=4.0, init_box=box)
    assert (upload.cameras["near"], upload.cameras["far"]) == (2.0, 4.0)
    assert upload.cameras["init_box"] == box
    assert "near" not in from_images(images, ring).cameras
    with pytest.raises(InvalidInput, match=r"near \(4.0\) must be less than far \(2.0\)"):
        from_images(images, ring, near=4.0, far=2.0)


# ---------------------------------------------------------------- camera helpers


def _centre_and_forward(cam: PinholeCamera) -> tuple[np.ndarray, np.ndarray]:
    m = np.array(cameras.camera_to_world_opencv(cam))
    return m[:3, 3], m[:3, 2]


def test_look_at_and_orbit() -> None:
    k = cameras.Intrinsics.from_fov(64, 48, 50)
    cam = cameras.look_at((1, -4, 2), (0.5, 0, 0), up=(0, 0, 1), intrinsics=k)
    centre, forward = _centre_and_forward(cam)
    target = np.array([0.5, 0, 0])
    np.testing.assert_allclose(forward, (target - centre) / np.linalg.norm(target - centre))
    # Image "up" (-y in OpenCV axes) points to +z in the world.
    assert -np.array(cameras.camera_to_world_opencv(cam))[2, 1] > 0
    ring = cameras.orbit((1, 2, 3), 5.0, 8, up=(0, 0, 1), elevation_deg=30, intrinsics=k)
    for c in ring:
        centre, forward = _centre_and_forward(c)
        assert math.isclose(np.linalg.norm(centre - [1, 2, 3]), 5.0, rel_tol=1e-9)
        assert math.isclose(centre[2] - 3, 5.0 * math.sin(math.radians(30)), rel_tol=1e-9)
    np.testing.assert_allclose(cameras.center_of_interest(ring), (1, 2, 3), atol=1e-9)
    fitted = cameras.orbit_around(ring, 8)
    for a, b in zip(fitted, ring, strict=True):
        np.testing.assert_allclose(a.matrix, b.matrix, atol=1e-6)
    with pytest.raises(InvalidInput, match="parallel"):
        cameras.look_at((0, 0, 4), (0, 0, 0), up=(0, 0, 1), intrinsics=k)


def test_from_matrix_conventions_agree() -> None:
    k = cameras.Intrinsics(50, 50, 16, 12, 32, 24)
    cv = cameras.look_at((0, -3, 1), (0, 0, 0), intrinsics=k)
    c2w = np.array(cv.matrix)
    gl_c2w = c2w @ np.diag([1, -1, -1, 1])
    forms = [
        cameras.from_matrix(c2w, convention="opencv", pose="camera_to_world", intrinsics=k),
        cameras.from_matrix(np.linalg.inv(c2w), convention="opencv", pose="world_to_camera",
                            intrinsics=k),
        cameras.from_matrix(gl_c2w, convention="opengl", pose="camera_to_world", intrinsics=k),
        cameras.from_matrix(np.linalg.inv(gl_c2w)[:3], convention="opengl",
                            pose="world_to_camera", fx=50, width=32, height=24, cy=12),
    ]  # fmt: skip
    for cam in forms:
        np.testing.assert_allclose(cameras.camera_to_world_opencv(cam), c2w, atol=1e-9)
        assert (cam.fx, cam.fy, cam.cx, cam.cy) == (50, 50, 16, 12)


def test_interpolation_slerps_rotation() -> None:
    k = cameras.Intrinsics.from_fov(32, 32, 40)
    a = cameras.look_at((4, 0, 0), (0, 0, 0), intrinsics=k)
    b = cameras.look_at((0, 4, 0), (0, 0, 0), intrinsics=k)
    path = cameras.interpolate(a, b, 5)
    np.testing.assert_allclose(path[0].matrix, a.matrix, atol=1e-9)
    np.testing.assert_allclose(path[-1].matrix, b.matrix, atol=1e-9)
    mid = np.array(path[2].matrix)
    np.testing.assert_allclose(mid[:3, :3].T @ mid[:3, :3], np.eye(3), atol=1e-9)
    # Halfway in rotation: the optical axis turned by 45 degrees from each end.
    fa, fm = _centre_and_forward(a)[1], mid[:3, 2]
    assert math.isclose(math.degrees(math.acos(float(fa @ fm))), 45.0, rel_tol=1e-6)
    np.testing.assert_allclose(mid[:3, 3], (2, 2, 0), atol=1e-9)  # centre: linear


@pytest.mark.shared_data
def test_dtu_held_out_frames_carry_the_object_masks_the_engine_scores_with() -> None:
    from sparsesplat.engine.datasets import load_scene

    upload = read_scene(SCENES["dtu"], test_views="all").validate()
    scene = load_scene(SCENES["dtu"])
    frames = upload.cameras["frames"]
    assert [f.get("mask") for f in frames if f["split"] == "train"] == [None] * 3
    held_out = [f for f in frames if f["split"] == "test"]
    assert len(held_out) == len(scene.test) == 25 and len(upload.masks) == 25
    for frame, view in zip(held_out, scene.test, strict=True):
        mask = media.decode_array(upload.masks[frame["mask"]])
        grey = mask if mask.ndim == 2 else mask[..., 0]
        assert view.mask is not None
        np.testing.assert_array_equal(grey >= 128, view.mask.numpy())
    small = read_scene(SCENES["dtu"], test_views=1, downscale=4)
    [frame] = [f for f in small.cameras["frames"] if f["split"] == "test"]
    assert media.image_size(small.masks[frame["mask"]]) == (frame["width"], frame["height"])
