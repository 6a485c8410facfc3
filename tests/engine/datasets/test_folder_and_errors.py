"""The upload folder format and the typed errors for bad input."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
import torch

from sparsesplat.engine.datasets import load_scene
from sparsesplat.engine.errors import SceneError
from tests.engine.datasets.synthetic import write_folder_scene


def _edit(root: Path, fn) -> None:  # type: ignore[no-untyped-def]
    meta = json.loads((root / "cameras.json").read_text())
    fn(meta)
    (root / "cameras.json").write_text(json.dumps(meta))


def test_folder_scene_loads(tmp_path: Path) -> None:
    root = write_folder_scene(tmp_path / "s", count=5, depth=True)
    scene = load_scene(root)
    assert scene.format == "folder" and len(scene.train) == 4 and len(scene.test) == 1
    assert scene.train_indices == [0, 1, 2, 3] and scene.test_indices == [4]
    view = scene.train[0]
    assert view.depth is not None and torch.allclose(view.depth, torch.full((32, 48), 3.0))
    # The camera looks at the origin from distance 3: the origin projects to the centre.
    pix = view.camera.world_to_camera[:3, 3]
    assert abs(float(pix[2]) - 3.0) < 1e-5 and abs(float(pix[0])) < 1e-5
    assert 2.0 < scene.near < 3.0 < scene.far < 4.0, "bounds come from the user depth"
    assert len(load_scene(root, views=2).train) == 2


def test_bounds_and_init_box_from_cameras_json(tmp_path: Path) -> None:
    """Given bounds win over the user depth and the optical-axes estimate; per-frame bounds
    set the scene's range (nearest near, farthest far) and narrow the init box."""
    root = write_folder_scene(tmp_path / "s", count=5, depth=True)
    guessed = load_scene(root)
    _edit(root, lambda m: m.update(near=1.5, far=4.5, init_box=[[-1, -2, -3], [1, 2, 3]]))
    given = load_scene(root)
    assert (given.near, given.far) == (1.5, 4.5)
    assert given.init_box == ((-1.0, -2.0, -3.0), (1.0, 2.0, 3.0))

    def per_frame(meta: dict) -> None:
        for key in ("near", "far", "init_box"):
            meta.pop(key)
        for i, frame in enumerate(meta["frames"]):
            frame.update(near=2.8 - 0.05 * i, far=3.2 + 0.05 * i)

    _edit(root, per_frame)
    framed = load_scene(root)
    assert framed.near == pytest.approx(2.6) and framed.far == pytest.approx(3.4)
    assert (guessed.near, guessed.far) == pytest.approx((2.4, 3.75)), "depth 3 with margins"
    narrow, wide = np.array(framed.init_box), np.array(guessed.init_box)
    # The cameras stand 3 units from the origin: depths within 0.4 of 3 keep the box within
    # about 0.5 of the origin along the view direction, smaller than the depth maps' range.
    assert np.all(narrow[1] - narrow[0] < wide[1] - wide[0])


def test_opengl_convention_gives_same_cameras(tmp_path: Path) -> None:
    root = write_folder_scene(tmp_path / "s")
    cv = load_scene(root)

    def to_gl(meta: dict) -> None:
        meta["convention"] = "opengl"
        for f in meta["frames"]:
            f["matrix"] = (np.array(f["matrix"]) @ np.diag([1.0, -1.0, -1.0, 1.0])).tolist()

    _edit(root, to_gl)
    gl = load_scene(root)
    for a, b in zip(cv.train, gl.train, strict=True):
        assert torch.allclose(a.camera.world_to_camera, b.camera.world_to_camera, atol=1e-6)


@pytest.mark.parametrize(
    "breaker, message",
    [
        (lambda m: m["frames"][0].update(matrix=[[float("nan")] * 4] * 4), "NaN"),
        (lambda m: m["frames"][1]["matrix"][0].__setitem__(0, 3.0), "not rigid"),
        (lambda m: m["frames"][0].update(width=99), "99x32"),
        (lambda m: m["frames"][0].update(image="missing.png"), "not found"),
        (lambda m: [f.update(split="test") for f in m["frames"][1:]], "at least 2"),
        (lambda m: m.update(convention="weird"), "convention"),
        (lambda m: m["frames"][0].update(depth="nodepth.npy"), "nodepth.npy"),
        (lambda m: m.update(near=2.0, far=1.0), r"near \(2.0\) must be less than far"),
        (lambda m: m.update(init_box=[[1, 0, 0], [0, 1, 1]]), "init_box: the first corner"),
        (
            lambda m: (
                m.update(far=3.5),
                m["frames"][0].update(near=4),
                m["frames"][1].update(near=1),
            ),
            "frame 'view_0.png': near 4 is not below far 3.5",
        ),
    ],
)
def test_bad_folder_input_raises_scene_error(tmp_path: Path, breaker, message: str) -> None:  # type: ignore[no-untyped-def]
    root = write_folder_scene(tmp_path / "s")
    _edit(root, breaker)
    with pytest.raises(SceneError, match=message):
        load_scene(root)


def test_truncated_and_garbage_images(tmp_path: Path) -> None:
    root = write_folder_scene(tmp_path / "s")
    data = (root / "view_1.png").read_bytes()
    (root / "view_1.png").write_bytes(data[: len(data) // 2])
    with pytest.raises(SceneError, match=r"view_1\.png"):
        load_scene(root)
    (root / "view_1.png").write_bytes(b"not an image at all")
    with pytest.raises(SceneError, match=r"view_1\.png"):
        load_scene(root)


def test_image_size_disagrees_with_intrinsics(tmp_path: Path) -> None:
    root = write_folder_scene(tmp_path / "s")
    _edit(root, lambda m: m["frames"][2].pop("width"))
    from PIL import Image

    Image.new("RGB", (20, 20)).save(root / "view_2.png")
    _edit(root, lambda m: m["frames"][2].update(width=48, height=32))
    with pytest.raises(SceneError, match=r"view_2\.png"):
        load_scene(root)


def test_missing_and_unknown_folders(tmp_path: Path) -> None:
    with pytest.raises(SceneError, match="not found"):
        load_scene(tmp_path / "nope")
    (tmp_path / "empty").mkdir()
    with pytest.raises(SceneError, match="unknown scene format"):
        load_scene(tmp_path / "empty")


def test_llff_errors(tmp_path: Path) -> None:
    root = tmp_path / "llff"
    (root / "images").mkdir(parents=True)
    from PIL import Image

    for i in range(10):
        Image.new("RGB", (32, 24)).save(root / "images" / f"{i:03d}.png")
    rows = np.zeros((10, 17))
    for i in range(10):
        mat = np.zeros((3, 5))
        mat[:, :3] = [[0, 1, 0], [1, 0, 0], [0, 0, -1]]
        mat[:, 4] = [24, 32, 40]
        rows[i, :15], rows[i, 15:] = mat.reshape(-1), [1, 5]
    rows[3, 0] = 2.0  # non-rigid rotation in row 3
    np.save(root / "poses_bounds.npy", rows)
    with pytest.raises(SceneError, match="row 3"):
        load_scene(root)
    rows[3, 0] = 0.0
    np.save(root / "poses_bounds.npy", rows[:9])
    with pytest.raises(SceneError, match="9 poses but 10 images"):
        load_scene(root)
    np.save(root / "poses_bounds.npy", rows)
    scene = load_scene(root, views=2)
    assert scene.train_indices == [1, 9] and scene.test_indices == [0, 8]


def test_png_depth_with_scale(tmp_path: Path) -> None:
    from PIL import Image

    root = write_folder_scene(tmp_path / "s")
    depth_mm = np.full((32, 48), 2500, dtype=np.uint16)
    Image.fromarray(depth_mm).save(root / "d0.png")

    def add(meta: dict) -> None:
        meta["depth_scale"] = 1000.0
        meta["frames"][0]["depth"] = "d0.png"

    _edit(root, add)
    scene = load_scene(root)
    assert scene.train[0].depth is not None
    assert torch.allclose(scene.train[0].depth, torch.full((32, 48), 2.5))


def test_exif_rotation_is_applied(tmp_path: Path) -> None:
    from PIL import Image

    from sparsesplat.engine.images import image_size, read_rgb

    img = Image.new("RGB", (40, 20), (255, 0, 0))
    img.paste((0, 0, 255), (0, 0, 10, 20))  # blue strip on the left
    exif = Image.Exif()
    exif[0x0112] = 6  # "rotate 90 CW to display"
    img.save(tmp_path / "r.jpg", exif=exif, quality=100)
    assert image_size(tmp_path / "r.jpg") == (20, 40)
    arr = read_rgb(tmp_path / "r.jpg")
    assert arr.shape == (40, 20, 3)
    assert arr[2, 10, 2] > 0.8 and arr[-2, 10, 0] > 0.8, "left strip must end up on top"


def test_object_mask_of_a_held_out_frame(tmp_path: Path) -> None:
    """A frame's ``mask`` becomes ``View.mask`` (white = object), shrunk with the image;
    the held-out scores then follow the DTU protocol (tests/engine/metrics)."""
    from PIL import Image

    root = write_folder_scene(tmp_path / "s", count=4)
    mask = np.zeros((32, 48), np.uint8)
    mask[8:24, 12:36] = 255
    Image.fromarray(mask).save(root / "held_out_mask.png")
    _edit(root, lambda meta: meta["frames"][3].update(mask="held_out_mask.png"))
    scene = load_scene(root)
    assert scene.train[0].mask is None
    held_out = scene.test[0].mask
    assert held_out is not None and torch.equal(held_out, torch.from_numpy(mask == 255))
    half = load_scene(root, downscale=2).test[0].mask
    assert half is not None and torch.equal(half, torch.from_numpy(mask[::2, ::2] == 255))
    (root / "held_out_mask.png").unlink()
    with pytest.raises(SceneError, match=r"held_out_mask\.png"):
        load_scene(root)


def test_an_object_upload_without_bounds_is_framed_by_what_every_camera_sees(
    tmp_path: Path,
) -> None:
    """Three views around an object at radius 4 (NeRF-synthetic's layout), no bounds given:
    the box is about the object's [-1, 1] cube rather than the region two frusta share out to
    3x the look-at depth, and near/far are its depths (about the format's 2 and 6)."""
    from sparsesplat.engine.camera import Camera
    from sparsesplat.engine.datasets.common import common_view, covisible_box, look_at_bounds

    cameras = []
    for azimuth in (10.0, 120.0, 230.0):
        a, e = np.radians(azimuth), np.radians(30.0)
        eye = 4.0 * np.array([np.cos(a) * np.cos(e), np.sin(a) * np.cos(e), np.sin(e)])
        forward = -eye / np.linalg.norm(eye)  # OpenCV axes: +z forward, +y down
        right = np.cross(forward, [0.0, 0.0, 1.0])
        right /= np.linalg.norm(right)
        down = np.cross(forward, right)
        w2c = np.eye(4)
        w2c[:3, :3] = np.stack([right, down, forward])
        w2c[:3, 3] = -w2c[:3, :3] @ eye
        focal = 100 / np.tan(np.radians(20.0))
        cameras.append(Camera(torch.tensor(w2c).float(), focal, focal, 100.0, 100.0, 200, 200))
    seen = common_view(cameras)
    assert seen is not None
    low, high = np.array(seen.box)
    assert np.all(low > -1.5) and np.all(high < 1.5) and np.all(low < -0.5) and np.all(high > 0.5)
    assert 1.5 < seen.near < 2.8 and 5.0 < seen.far < 7.0
    near, far = look_at_bounds(cameras)
    wide = np.array(covisible_box(cameras, [near] * 3, [far] * 3))
    assert np.prod(high - low) < 0.8 * np.prod(wide[1] - wide[0])
    # A forward-facing capture has no common look-at: no estimate, the wide rule stays.
    forward_facing = [
        Camera(torch.tensor([[1, 0, 0, -0.1 * i], [0, 1, 0, 0], [0, 0, 1, 0], [0, 0, 0, 1.0]]),
               100.0, 100.0, 50.0, 50.0, 100, 100)
        for i in range(3)
    ]  # fmt: skip
    assert common_view(forward_facing) is None
