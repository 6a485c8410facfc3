"""Camera converters: round trips, one 3D point -> one pixel through every convention, errors."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from sparsesplat.engine.camera import Camera
from sparsesplat.engine.camera_convert import (
    camera_from_neus,
    camera_from_projection,
    camera_from_transforms_frame,
    cameras_from_llff,
    intrinsics_from_transforms,
    llff_from_w2c,
    neus_from_camera,
    opengl_c2w_from_w2c,
    project,
    rigid_inverse,
    rq_decomposition,
    transforms_frame_from_camera,
    w2c_from_llff,
    w2c_from_opencv_c2w,
    w2c_from_opengl_c2w,
    w2c_from_opengl_w2c,
)
from sparsesplat.engine.errors import CameraError


def random_rotation(rng: np.random.Generator) -> np.ndarray:
    q, r = np.linalg.qr(rng.normal(size=(3, 3)))
    q = q * np.sign(np.diag(r))
    if np.linalg.det(q) < 0:
        q[:, 0] = -q[:, 0]
    return q


def random_camera(rng: np.random.Generator) -> Camera:
    """A camera looking at the origin from distance 3-5, with a point near the origin in view."""
    w2c = np.eye(4)
    w2c[:3, :3] = random_rotation(rng)
    w2c[:3, 3] = np.array([0.0, 0.0, rng.uniform(3, 5)])  # origin sits on the optical axis
    return Camera(torch.from_numpy(w2c).double(), 500.0, 480.0, 320.5, 240.25, 640, 480)


@pytest.fixture
def rng(seed: int) -> tuple[np.random.Generator, int]:
    """A numpy generator from the test's seed (tests/conftest.py), and the seed."""
    return np.random.default_rng(seed), seed


def test_rq_decomposition_recovers_factors(rng: tuple[np.random.Generator, int]) -> None:
    gen, seed = rng
    k = np.array([[600.0, 0.0, 300.0], [0.0, 610.0, 200.0], [0.0, 0.0, 1.0]])
    r = random_rotation(gen)
    k2, r2 = rq_decomposition(k @ r)
    assert np.allclose(k2 / k2[2, 2], k, atol=1e-8), f"seed={seed}"
    assert np.allclose(r2 * np.sign(k2[2, 2]), r, atol=1e-8), f"seed={seed}"


def test_round_trips_are_identity(rng: tuple[np.random.Generator, int]) -> None:
    gen, seed = rng
    cam = random_camera(gen)
    w2c = cam.world_to_camera
    back = w2c_from_opengl_c2w(opengl_c2w_from_w2c(w2c)).double()
    assert torch.allclose(back, w2c, atol=1e-5), f"opengl seed={seed}"
    back = w2c_from_llff(llff_from_w2c(w2c)).double()
    assert torch.allclose(back, w2c, atol=1e-5), f"llff seed={seed}"
    scale_mat = np.diag([2.5, 2.5, 2.5, 1.0])
    scale_mat[:3, 3] = gen.normal(size=3)
    neus = camera_from_neus(neus_from_camera(cam, scale_mat), scale_mat, 640, 480)
    assert torch.allclose(neus.world_to_camera.double(), w2c, atol=1e-4), f"neus seed={seed}"
    assert np.allclose(
        [neus.fx, neus.fy, neus.cx, neus.cy], [cam.fx, cam.fy, cam.cx, cam.cy], atol=1e-3
    ), f"neus intrinsics seed={seed}"
    back = w2c_from_opencv_c2w(rigid_inverse(w2c.numpy())).double()
    assert torch.allclose(back, w2c, atol=1e-5), f"opencv seed={seed}"
    frame = transforms_frame_from_camera(cam)
    ngp = camera_from_transforms_frame({}, frame, cam.width, cam.height)
    assert torch.allclose(ngp.world_to_camera.double(), w2c, atol=1e-5), f"ngp seed={seed}"
    assert (ngp.fx, ngp.fy, ngp.cx, ngp.cy) == (cam.fx, cam.fy, cam.cx, cam.cy)
    half = camera_from_transforms_frame({}, frame, cam.width // 2, cam.height // 2)
    assert half.fx == cam.fx / 2 and half.cy == cam.cy / 2, "intrinsics follow the image size"


def test_same_point_same_pixel_through_every_convention(
    rng: tuple[np.random.Generator, int],
) -> None:
    gen, seed = rng
    cam = random_camera(gen)
    point = torch.from_numpy(gen.normal(scale=0.3, size=(1, 3)))
    expected, z = project(cam, point)
    assert z.item() > 0, f"seed={seed}"
    w2c = cam.world_to_camera
    # OpenGL c2w: project with the OpenGL formula directly (y up, looking down -z).
    c2w_gl = opengl_c2w_from_w2c(w2c)
    p_gl = rigid_inverse(c2w_gl) @ np.append(point.numpy()[0], 1.0)
    u_gl = cam.fx * p_gl[0] / -p_gl[2] + cam.cx
    v_gl = -cam.fy * p_gl[1] / -p_gl[2] + cam.cy
    assert np.allclose([u_gl, v_gl], expected.numpy()[0], atol=1e-6), f"gl seed={seed}"
    # LLFF: rebuild the poses_bounds row (full-res hwf at 2x) and parse it at half size.
    row = np.zeros(17)
    mat = np.zeros((3, 5))
    mat[:, :4] = llff_from_w2c(w2c)
    mat[:, 4] = [960, 1280, cam.fx * 2]
    row[:15], row[15:] = mat.reshape(-1), [1.0, 10.0]
    llff_cam = cameras_from_llff(row[None], (480, 640))[0][0]
    llff_cam = Camera(llff_cam.world_to_camera, cam.fx, cam.fy, cam.cx, cam.cy, 640, 480)
    assert torch.allclose(project(llff_cam, point)[0], expected, atol=1e-3), f"llff seed={seed}"
    # NeuS: P = world_mat @ scale_mat projects normalised-frame points directly.
    scale_mat = np.diag([3.0, 3.0, 3.0, 1.0])
    world_mat = neus_from_camera(cam, scale_mat)
    hom = (world_mat @ scale_mat)[:3] @ np.append(point.numpy()[0], 1.0)
    assert np.allclose(hom[:2] / hom[2], expected.numpy()[0], atol=1e-6), f"neus seed={seed}"
    # OpenGL w2c and transforms.json frames.
    gl_w2c = rigid_inverse(c2w_gl)
    cam2 = Camera(w2c_from_opengl_w2c(gl_w2c).double(), cam.fx, cam.fy, cam.cx, cam.cy, 640, 480)
    assert torch.allclose(project(cam2, point)[0], expected, atol=1e-3), f"gl w2c seed={seed}"


def test_llff_layout_down_right_back() -> None:
    # A camera at the origin with identity OpenCV rotation: right = +x, down = +y, back = -z.
    pose = np.array([[0.0, 1.0, 0.0, 0.0], [1.0, 0.0, 0.0, 0.0], [0.0, 0.0, -1.0, 0.0]])
    w2c = w2c_from_llff(pose)
    assert torch.allclose(w2c, torch.eye(4))


def test_projection_decomposition_matches_known_camera() -> None:
    k = np.array([[723.0, 0.0, 205.8], [0.0, 720.8, 154.8], [0.0, 0.0, 1.0]])
    r = random_rotation(np.random.default_rng(3))
    t = np.array([0.1, -0.2, 2.8])
    p = 7.5 * k @ np.hstack([r, t[:, None]])  # projection matrices are defined up to scale
    cam = camera_from_projection(p, 400, 300)
    assert np.allclose(cam.world_to_camera[:3, :3].double().numpy(), r, atol=1e-5)
    assert np.allclose(cam.world_to_camera[:3, 3].double().numpy(), t, atol=1e-5)
    assert abs(cam.fx - 723.0) < 1e-3 and abs(cam.cy - 154.8) < 1e-3


def test_transforms_intrinsics_rescale_and_fallback() -> None:
    meta = {"fl_x": 100.0, "fl_y": 110.0, "cx": 50.0, "cy": 40.0, "w": 100, "h": 80}
    assert intrinsics_from_transforms(meta, {}, 50, 40, "t") == (50.0, 55.0, 25.0, 20.0)
    fx, fy, cx, cy = intrinsics_from_transforms({"camera_angle_x": np.pi / 2}, {}, 200, 100, "t")
    assert abs(fx - 100.0) < 1e-9 and fy == fx and (cx, cy) == (100.0, 50.0)


@pytest.mark.parametrize(
    "matrix, message",
    [
        (np.diag([1.0, 1.0, 2.0, 1.0]), "not rigid"),
        (np.diag([1.0, 1.0, -1.0, 1.0]), "not rigid"),  # a reflection
        (np.full((4, 4), np.nan), "NaN"),
        (np.eye(3), "shape"),
    ],
)
def test_bad_matrices_raise_camera_error(matrix: np.ndarray, message: str) -> None:
    with pytest.raises(CameraError, match=message) as info:
        w2c_from_opengl_c2w(matrix, "frame r_7")
    assert "frame r_7" in str(info.value)


def test_llff_nan_row_named() -> None:
    rows = np.zeros((3, 17))
    rows[1, 0] = np.inf
    with pytest.raises(CameraError, match="row 1"):
        cameras_from_llff(rows, (10, 10), "poses_bounds.npy")


def test_undistort_moves_a_dot_back_to_its_pinhole_pixel() -> None:
    from sparsesplat.engine.camera_convert import undistort_image

    h, w, f, cx, cy = 120, 160, 100.0, 80.0, 60.0
    coeffs = (0.15, -0.02, 0.001, -0.002)
    # Pinhole pixel (130.5, 100.5) -> where the lens images it.
    x, y = (130.5 - cx) / f, (100.5 - cy) / f
    r2 = x * x + y * y
    radial = 1 + coeffs[0] * r2 + coeffs[1] * r2 * r2
    xd = x * radial + 2 * coeffs[2] * x * y + coeffs[3] * (r2 + 2 * x * x)
    yd = y * radial + coeffs[2] * (r2 + 2 * y * y) + 2 * coeffs[3] * x * y
    ud, vd = xd * f + cx, yd * f + cy
    image = np.zeros((h, w, 3), dtype=np.float32)
    image[int(vd) - 1 : int(vd) + 2, int(ud) - 1 : int(ud) + 2] = 1.0
    assert abs(ud - 130.5) + abs(vd - 100.5) > 2.5, "the test dot must actually move"
    out = undistort_image(image, f, f, cx, cy, coeffs)
    v, u = np.unravel_index(np.argmax(out[..., 0]), out.shape[:2])
    assert abs(u + 0.5 - 130.5) <= 1.5 and abs(v + 0.5 - 100.5) <= 1.5
    assert undistort_image(image, f, f, cx, cy, (0.0, 0.0, 0.0, 0.0)) is image
