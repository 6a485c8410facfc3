"""Converters between foreign camera conventions and the internal one (engine.camera).

Internal: world-to-camera 4x4 in OpenCV axes (+x right, +y down, +z forward). Every converter
validates its input: NaN/inf anywhere, or a rotation that is not orthonormal with det +1, raises
:class:`CameraError` naming ``source`` (the file / frame the matrix came from).

Intrinsics read from files are used as given: the datasets here store principal points in the
continuous image frame (pixel centres at +0.5), which is the internal convention.
"""

from __future__ import annotations

from typing import Any

import numpy as np
import torch
from torch import Tensor

from sparsesplat.api.cameras import AxisConvention, PoseDirection
from sparsesplat.api.cameras import rigid_inverse as rigid_inverse_lists
from sparsesplat.api.scenes import dtu as dtu_format
from sparsesplat.api.scenes import llff as llff_format
from sparsesplat.api.scenes import transforms as transforms_format
from sparsesplat.engine.camera import Camera
from sparsesplat.engine.errors import CameraError, reraise_as

ROTATION_TOLERANCE = 1e-3
"""Max |R^T R - I| and |det R - 1| accepted as a rigid rotation (float32 files round at ~1e-7,
but LLFF/COLMAP exports keep only a few digits)."""

# OpenGL/Blender axes (+x right, +y up, +z back) to OpenCV axes: flip y and z.
_FLIP_YZ = np.diag([1.0, -1.0, -1.0, 1.0])


def as_matrix(value: Any, shape: tuple[int, ...], source: str) -> np.ndarray:
    """Return ``value`` as a float64 array of ``shape``; raise CameraError naming ``source``."""
    try:
        array = np.asarray(
            value.detach().cpu().numpy() if isinstance(value, Tensor) else value, dtype=np.float64
        )
    except (TypeError, ValueError) as exc:
        raise CameraError(f"{source}: camera matrix is not numeric ({exc})") from exc
    if array.shape != shape:
        raise CameraError(f"{source}: camera matrix has shape {array.shape}, expected {shape}")
    if not np.all(np.isfinite(array)):
        raise CameraError(f"{source}: camera matrix contains NaN or inf")
    return array


def check_rotation(rotation: np.ndarray, source: str) -> None:
    """Raise CameraError unless ``rotation`` (3x3) is orthonormal with determinant +1."""
    if not np.all(np.isfinite(rotation)):
        raise CameraError(f"{source}: rotation contains NaN or inf")
    err = np.abs(rotation.T @ rotation - np.eye(3)).max()
    det = float(np.linalg.det(rotation))
    if err > ROTATION_TOLERANCE or abs(det - 1.0) > ROTATION_TOLERANCE:
        raise CameraError(
            f"{source}: rotation is not rigid (max |R^T R - I| = {err:.2e}, det = {det:.4f})"
        )


def rigid_inverse(matrix: np.ndarray) -> np.ndarray:
    """Inverse of a 4x4 rigid transform (``api.cameras.rigid_inverse``, (R^T, -R^T t)), as a
    float64 array."""
    return np.array(rigid_inverse_lists(np.asarray(matrix, dtype=np.float64).tolist()))


def _bottom_row_ok(matrix: np.ndarray, source: str) -> None:
    if np.abs(matrix[3] - np.array([0.0, 0.0, 0.0, 1.0])).max() > 1e-6:
        raise CameraError(f"{source}: last row of the 4x4 pose is {matrix[3]}, expected [0 0 0 1]")


def w2c_from_opencv_c2w(c2w: Any, source: str = "pose") -> Tensor:
    """OpenCV camera-to-world (4x4) -> internal world-to-camera (float32 tensor)."""
    m = as_matrix(c2w, (4, 4), source)
    _bottom_row_ok(m, source)
    check_rotation(m[:3, :3], source)
    return torch.from_numpy(rigid_inverse(m)).float()


def w2c_from_opencv_w2c(w2c: Any, source: str = "pose") -> Tensor:
    """OpenCV world-to-camera (4x4), validated -> internal pose (float32 tensor)."""
    m = as_matrix(w2c, (4, 4), source)
    _bottom_row_ok(m, source)
    check_rotation(m[:3, :3], source)
    return torch.from_numpy(m).float()


def w2c_from_opengl_c2w(c2w: Any, source: str = "pose") -> Tensor:
    """OpenGL/Blender/NeRF camera-to-world (+y up, +z back) -> internal world-to-camera."""
    m = as_matrix(c2w, (4, 4), source)
    _bottom_row_ok(m, source)
    check_rotation(m[:3, :3], source)
    return torch.from_numpy(rigid_inverse(m @ _FLIP_YZ)).float()


def opengl_c2w_from_w2c(w2c: Tensor) -> np.ndarray:
    """Internal world-to-camera -> OpenGL/Blender camera-to-world (inverse of the above)."""
    m = as_matrix(w2c, (4, 4), "pose")
    return rigid_inverse(m) @ _FLIP_YZ


def file_pose_from_w2c(
    w2c: Tensor, convention: AxisConvention | str, pose: PoseDirection | str
) -> list[list[float]]:
    """Internal world-to-camera -> the 4x4 a ``cameras.json`` holds in ``convention`` axes and
    ``pose`` direction (the inverse of ``api.cameras.to_world_to_camera_opencv``), float64."""
    m = as_matrix(w2c, (4, 4), "pose")
    if AxisConvention(convention) == AxisConvention.opengl:
        m = _FLIP_YZ @ m  # the camera's y and z axes flipped; the flip is its own inverse
    if PoseDirection(pose) == PoseDirection.camera_to_world:
        m = rigid_inverse(m)
    return m.tolist()


def w2c_from_opengl_w2c(w2c: Any, source: str = "pose") -> Tensor:
    """OpenGL world-to-camera -> internal world-to-camera (flip the camera's y and z axes)."""
    m = as_matrix(w2c, (4, 4), source)
    _bottom_row_ok(m, source)
    check_rotation(m[:3, :3], source)
    return torch.from_numpy(_FLIP_YZ @ m).float()


# ---------------------------------------------------------------- LLFF poses_bounds.npy


def cameras_from_llff(
    poses_bounds: np.ndarray, image_size: tuple[int, int], source: str = "poses_bounds.npy"
) -> tuple[list[Camera], np.ndarray]:
    """Parse LLFF ``poses_bounds.npy`` rows (N, 17) into cameras for images of ``image_size``
    (height, width), plus the (N, 2) near/far bounds.

    Each row is a 3x5 matrix [R | t | hwf] flattened row-major, then near, far. The rotation
    columns are the camera's [down, right, back] axes in world coordinates, t is the camera
    centre, hwf is the FULL-resolution height, width, focal. The focal is rescaled by the ratio
    of ``image_size`` to the full-resolution size (the aspect must agree).
    """
    pb = np.asarray(poses_bounds, dtype=np.float64)
    if pb.ndim != 2 or pb.shape[1] != 17:
        raise CameraError(f"{source}: expected an (N, 17) array, got shape {pb.shape}")
    if not np.all(np.isfinite(pb)):
        bad = int(np.where(~np.isfinite(pb).all(axis=1))[0][0])
        raise CameraError(f"{source}: row {bad} contains NaN or inf")
    height, width = image_size
    cameras = []
    for i, row in enumerate(pb):
        with reraise_as(CameraError):
            fx, fy, cx, cy = llff_format.intrinsics(row, width, height, f"{source} row {i}")
        w2c = w2c_from_llff(row[:15].reshape(3, 5)[:, :4], f"{source} row {i}")
        cameras.append(Camera(w2c, fx, fy, cx, cy, width, height))
    return cameras, pb[:, 15:17].copy()


def w2c_from_llff(pose34: Any, source: str = "poses_bounds.npy") -> Tensor:
    """LLFF 3x4 [down, right, back | centre] camera-to-world -> internal world-to-camera."""
    c2w = llff_format.camera_to_world(as_matrix(pose34, (3, 4), source))
    check_rotation(c2w[:3, :3], source)
    return torch.from_numpy(rigid_inverse(c2w)).float()


def llff_from_w2c(w2c: Tensor) -> np.ndarray:
    """Internal world-to-camera -> LLFF 3x4 [down, right, back | centre] (inverse of above)."""
    c2w = rigid_inverse(as_matrix(w2c, (4, 4), "pose"))
    out = np.zeros((3, 4))
    out[:, 0], out[:, 1], out[:, 2], out[:, 3] = c2w[:3, 1], c2w[:3, 0], -c2w[:3, 2], c2w[:3, 3]
    return out


# ---------------------------------------------------------------- NeuS / IDR cameras_sphere


rq_decomposition = dtu_format.rq_decomposition


def camera_from_projection(
    projection: Any, width: int, height: int, source: str = "projection"
) -> Camera:
    """Decompose a 3x4 (or 4x4) projection P = s K [R | t] into an internal camera."""
    p = np.asarray(projection, dtype=np.float64)
    if p.shape == (4, 4):
        p = p[:3]
    p = as_matrix(p, (3, 4), source)
    with reraise_as(CameraError):
        k, w2c = dtu_format.decompose_projection(p, source)
    check_rotation(w2c[:3, :3], source)
    return Camera(
        torch.from_numpy(w2c).float(),
        float(k[0, 0]),
        float(k[1, 1]),
        float(k[0, 2]),
        float(k[1, 2]),
        width,
        height,
    )


def camera_from_neus(
    world_mat: Any, scale_mat: Any, width: int, height: int, source: str = "cameras_sphere.npz"
) -> Camera:
    """NeuS/IDR: P = world_mat @ scale_mat maps the normalised (unit-sphere) frame to pixels;
    decompose it into an internal camera in that normalised frame."""
    wm = as_matrix(world_mat, (4, 4), source)
    sm = as_matrix(scale_mat, (4, 4), source)
    return camera_from_projection((wm @ sm)[:3], width, height, source)


def neus_from_camera(camera: Camera, scale_mat: np.ndarray) -> np.ndarray:
    """Internal camera (in the normalised frame) -> NeuS ``world_mat`` for ``scale_mat``."""
    k = np.eye(4)
    k[:3, :3] = camera.K.double().numpy()
    p = k @ as_matrix(camera.world_to_camera, (4, 4), "pose")
    return p @ np.linalg.inv(scale_mat)


# ---------------------------------------------------------------- instant-ngp transforms.json


def intrinsics_from_transforms(
    meta: dict[str, Any], frame: dict[str, Any], width: int, height: int, source: str
) -> tuple[float, float, float, float]:
    """fx, fy, cx, cy for one frame of a NeRF/instant-ngp/nerfstudio ``transforms.json``
    (:func:`sparsesplat.api.scenes.transforms.intrinsics`; CameraError when malformed)."""
    with reraise_as(CameraError):
        return transforms_format.intrinsics(meta, frame, width, height, source)


def project(camera: Camera, points: Tensor) -> tuple[Tensor, Tensor]:
    """Project world points (N, 3) to continuous pixel coordinates (N, 2) and view depth (N,)."""
    w2c = camera.world_to_camera.to(points.dtype)
    cam = points @ w2c[:3, :3].T + w2c[:3, 3]
    z = cam[:, 2]
    u = camera.fx * cam[:, 0] / z + camera.cx
    v = camera.fy * cam[:, 1] / z + camera.cy
    return torch.stack([u, v], dim=-1), z


# ---------------------------------------------------------------- lens distortion


def distortion_from_transforms(meta: dict[str, Any], frame: dict[str, Any]) -> tuple[float, ...]:
    """OpenCV (k1, k2, p1, p2) from a transforms.json frame / header (zeros when absent)."""
    with reraise_as(CameraError):
        return transforms_format.distortion(meta, frame, "transforms.json")


def undistort_image(
    image: np.ndarray, fx: float, fy: float, cx: float, cy: float, coeffs: tuple[float, ...]
) -> np.ndarray:
    """Resample an (H, W, C) image taken through an OpenCV radial-tangential lens
    (k1, k2, p1, p2) into the ideal pinhole image with the same intrinsics.

    Each output pixel's normalised ray is pushed through the distortion model to find where
    the lens imaged it; the input is sampled there bilinearly (outside = 0)."""
    if not any(coeffs):
        return image
    import torch.nn.functional as F

    h, w = image.shape[:2]
    k1, k2, p1, p2 = coeffs
    xs, ys = transforms_format.distorted_pixels(w, h, (fx, fy, cx, cy), (k1, k2, p1, p2))
    grid = np.stack([xs / w * 2 - 1, ys / h * 2 - 1], axis=-1)
    src = torch.from_numpy(np.ascontiguousarray(image, dtype=np.float32)).permute(2, 0, 1)[None]
    out = F.grid_sample(
        src, torch.from_numpy(grid).float()[None], mode="bilinear", align_corners=False
    )
    return out[0].permute(1, 2, 0).numpy()


def transforms_frame_from_camera(camera: Camera) -> dict[str, Any]:
    """Internal camera -> an instant-ngp/nerfstudio ``transforms.json`` frame (per-frame
    intrinsics, OpenGL camera-to-world); the inverse of :func:`camera_from_transforms_frame`."""
    return {
        "fl_x": camera.fx,
        "fl_y": camera.fy,
        "cx": camera.cx,
        "cy": camera.cy,
        "w": camera.width,
        "h": camera.height,
        "transform_matrix": opengl_c2w_from_w2c(camera.world_to_camera).tolist(),
    }


def camera_from_transforms_frame(
    meta: dict[str, Any], frame: dict[str, Any], width: int, height: int, source: str = "frame"
) -> Camera:
    """One transforms.json frame (header ``meta`` for shared keys) -> internal camera for an
    image of ``width`` x ``height``."""
    w2c = w2c_from_opengl_c2w(frame.get("transform_matrix"), source)
    fx, fy, cx, cy = intrinsics_from_transforms(meta, frame, width, height, source)
    return Camera(w2c, fx, fy, cx, cy, width, height)
