"""The cameras file uploaded with a scene's images (``cameras.json``).

The pose convention is explicit, never guessed: ``convention`` names the camera axes and
``pose`` says which way the matrix maps. The engine's folder loader reads the same JSON.
"""

from __future__ import annotations

import math
from enum import StrEnum

from pydantic import BaseModel, ConfigDict, Field, field_validator, model_validator


def check_rigid_matrix(value: list[list[float]]) -> list[list[float]]:
    """Raise ValueError unless ``value`` is a finite rigid 4x4 with bottom row [0, 0, 0, 1]."""
    if len(value) != 4 or any(len(row) != 4 for row in value):
        raise ValueError("matrix must be 4x4 (a list of 4 rows of 4 numbers)")
    if not all(math.isfinite(x) for row in value for x in row):
        raise ValueError("matrix contains NaN or infinity")
    rot = [row[:3] for row in value[:3]]
    for i in range(3):
        for j in range(3):
            dot = sum(rot[k][i] * rot[k][j] for k in range(3))
            if abs(dot - (1.0 if i == j else 0.0)) > 1e-3:
                raise ValueError(
                    "matrix rotation block is not orthonormal (pose must be rigid)"
                )
    det = (
        rot[0][0] * (rot[1][1] * rot[2][2] - rot[1][2] * rot[2][1])
        - rot[0][1] * (rot[1][0] * rot[2][2] - rot[1][2] * rot[2][0])
        + rot[0][2] * (rot[1][0] * rot[2][1] - rot[1][1] * rot[2][0])
    )
    if det < 0:
        raise ValueError(
            "matrix rotation block has determinant -1 (a reflection, not a rotation): "
            "check that the axis convention is not applied twice"
        )
    if value[3] != [0.0, 0.0, 0.0, 1.0]:
        raise ValueError("matrix last row must be [0, 0, 0, 1]")
    return value


class AxisConvention(StrEnum):
    """Camera axes of the uploaded matrices."""

    opencv = "opencv"
    """+x right, +y down, +z forward (COLMAP, OpenCV, gsplat)."""
    opengl = "opengl"
    """+x right, +y up, +z backward (Blender, NeRF, nerfstudio)."""


class PoseDirection(StrEnum):
    """Which way the 4x4 matrix maps points."""

    camera_to_world = "camera_to_world"
    """Camera coordinates to world coordinates (the camera's placement in the world)."""
    world_to_camera = "world_to_camera"
    """World coordinates to camera coordinates (an extrinsic/view matrix)."""


class Split(StrEnum):
    """Role of an uploaded image."""

    train = "train"
    """Used for optimisation."""
    test = "test"
    """Held out: scored against renders while training (error against run time)."""


class CameraFrame(BaseModel):
    """One image with its pose and pinhole intrinsics (pixels; pixel centres at +0.5)."""

    image: str = Field(min_length=1)
    """File name of the image within the upload."""
    matrix: list[list[float]]
    """4x4 rigid pose, row-major, in the file's ``convention`` and ``pose`` direction."""
    fx: float = Field(gt=0)
    """Focal length along x in pixels."""
    fy: float = Field(gt=0)
    """Focal length along y in pixels."""
    cx: float
    """Principal point x in pixels."""
    cy: float
    """Principal point y in pixels."""
    width: int | None = Field(default=None, gt=0)
    """Image width in pixels; checked against the image when given."""
    height: int | None = Field(default=None, gt=0)
    """Image height in pixels; checked against the image when given."""
    depth: str | None = None
    """Optional depth map file (float ``.npy`` in scene units or 16-bit ``.png``)."""
    depth_scale: float | None = Field(default=None, gt=0)
    """Divisor turning integer depth PNG values into scene units (e.g. 1000 for millimetres);
    overrides the file-level ``depth_scale``."""
    split: Split = Split.train
    """Whether the frame is a training or a held-out view."""

    @field_validator("matrix")
    @classmethod
    def _check_matrix(cls, value: list[list[float]]) -> list[list[float]]:
        return check_rigid_matrix(value)


class CamerasFile(BaseModel):
    """Contents of ``cameras.json``."""

    convention: AxisConvention = AxisConvention.opencv
    """Camera axes the matrices use."""
    pose: PoseDirection = PoseDirection.camera_to_world
    """Direction of every matrix."""
    depth_scale: float = Field(default=1.0, gt=0)
    """Divisor turning integer depth PNG values into scene units, for every frame."""
    frames: list[CameraFrame] = Field(min_length=1)
    """The images, in any order."""

    @model_validator(mode="after")
    def _check_frames(self) -> CamerasFile:
        names = [f.image for f in self.frames]
        duplicates = sorted({n for n in names if names.count(n) > 1})
        if duplicates:
            raise ValueError(f"image listed more than once: {', '.join(duplicates)}")
        n_train = sum(f.split == Split.train for f in self.frames)
        if n_train < 2:
            raise ValueError(f"need at least 2 training views, got {n_train}")
        return self


class PinholeCamera(BaseModel):
    """One camera to render from: explicit pose convention, intrinsics and image size.

    ``convention`` and ``pose`` are required: a silent default is the most common pose bug.
    """

    model_config = ConfigDict(extra="forbid")

    convention: AxisConvention
    """Camera axes of ``matrix``: ``opencv`` (+y down, +z forward) or ``opengl`` (+y up, +z back)."""
    pose: PoseDirection
    """``camera_to_world`` (the camera's placement) or ``world_to_camera`` (a view matrix)."""
    matrix: list[list[float]]
    """4x4 rigid pose, row-major."""
    fx: float = Field(gt=0, allow_inf_nan=False)
    """Focal length along x in pixels."""
    fy: float = Field(gt=0, allow_inf_nan=False)
    """Focal length along y in pixels."""
    cx: float = Field(allow_inf_nan=False)
    """Principal point x in pixels (pixel centres at +0.5)."""
    cy: float = Field(allow_inf_nan=False)
    """Principal point y in pixels."""
    width: int = Field(gt=0)
    """Image width in pixels."""
    height: int = Field(gt=0)
    """Image height in pixels."""

    @field_validator("matrix")
    @classmethod
    def _check_matrix(cls, value: list[list[float]]) -> list[list[float]]:
        return check_rigid_matrix(value)

    def world_to_camera_opencv(self) -> list[list[float]]:
        """The pose as the engine uses it: world-to-camera in OpenCV axes (row-major 4x4)."""
        m = [list(row) for row in self.matrix]
        if self.pose == PoseDirection.camera_to_world:
            m = rigid_inverse(m)
        if self.convention == AxisConvention.opengl:
            # World-to-camera in OpenGL axes -> OpenCV axes: negate the camera's y and z rows.
            m = [m[0], [-x for x in m[1]], [-x for x in m[2]], m[3]]
        return m


def rigid_inverse(m: list[list[float]]) -> list[list[float]]:
    """Inverse of a rigid 4x4 ``[R t; 0 1]`` as ``[R^T, -R^T t; 0 1]`` (pure Python)."""
    rt = [[m[j][i] for j in range(3)] for i in range(3)]
    t = [-sum(rt[i][k] * m[k][3] for k in range(3)) for i in range(3)]
    return [rt[0] + [t[0]], rt[1] + [t[1]], rt[2] + [t[2]], [0.0, 0.0, 0.0, 1.0]]
