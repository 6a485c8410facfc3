"""The camera schemas on the wire: ``cameras.json`` (a scene's images) and one render camera.

The pose convention is explicit, never guessed: ``convention`` names the camera axes and
``pose`` says which way the matrix maps; both are required. Every model refuses unknown fields
and names the closest valid one ("unknown field 'convension' — did you mean 'convention'?"):
a typo must never fall back to a default. The engine's folder loader and ``sparsesplat render
--camera`` validate through these same models (pure pydantic, no heavy imports), so a file is
accepted or refused identically everywhere. ``docs/cameras.md`` documents the format.
"""

from __future__ import annotations

import difflib
import math
import re
from enum import StrEnum
from typing import Annotated, Any, ClassVar

from pydantic import (
    AfterValidator,
    BaseModel,
    BeforeValidator,
    ConfigDict,
    Field,
    ValidationError,
    field_validator,
    model_validator,
)

CONVENTION_HINT = (
    "say 'opencv' (+x right, +y down, +z forward: COLMAP/OpenCV) or "
    "'opengl' (+x right, +y up, +z back: Blender/NeRF)"
)
"""How to fill in a missing or wrong ``convention``."""
POSE_HINT = (
    "say 'camera_to_world' (the camera's placement in the world: Blender/NeRF "
    "transform_matrix, COLMAP's inverse) or 'world_to_camera' (a view/extrinsic matrix: "
    "COLMAP images.txt)"
)
"""How to fill in a missing or wrong ``pose``."""


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
                    "matrix is not rigid: its rotation block is not orthonormal (no scale or "
                    "shear allowed in the 3x3 block)"
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


Vec3 = tuple[float, float, float]
"""A point or vector in world units (x, y, z)."""


def check_bounds(near: float | None, far: float | None, where: str) -> None:
    """Near/far depth bounds: each optional, but ``near < far`` when both are given."""
    if near is not None and far is not None and not near < far:
        raise ValueError(f"{where}: near ({near}) must be less than far ({far})")


def _matrix_shape(value: Any) -> Any:
    """Before numeric parsing: a 4x4 nested list, or a ValueError saying what was given."""
    if not isinstance(value, list | tuple):
        raise ValueError(
            f"matrix must be 4x4 (a list of 4 rows of 4 numbers), got {type(value).__name__}"
        )
    rows = [r for r in value if isinstance(r, list | tuple)]
    if len(rows) != len(value):
        raise ValueError(
            f"matrix must be 4x4 (a list of 4 rows of 4 numbers), got a flat list of "
            f"{len(value)} values: nest it as 4 rows"
        )
    if len(rows) == 3 and all(len(r) == 4 for r in rows):
        raise ValueError("matrix must be 4x4: add the last row [0, 0, 0, 1] to the 3x4 pose")
    if len(rows) != 4 or any(len(r) != 4 for r in rows):
        shape = f"{len(rows)}x{'/'.join(sorted({str(len(r)) for r in rows})) or 0}"
        raise ValueError(f"matrix must be 4x4 (a list of 4 rows of 4 numbers), got {shape}")
    return value


def _relative_file(value: str, what: str) -> str:
    """A file name inside the scene folder: relative, no '..' components, no backslashes."""
    parts = value.replace("\\", "/").split("/")
    if value.startswith(("/", "\\")) or ":" in parts[0] or ".." in parts:
        raise ValueError(
            f"{what} {value!r} must be a relative path inside the scene folder (no '..', no "
            "absolute path)"
        )
    return value


def _unknown_field_message(
    name: str, valid: list[str], foreign: dict[str, str], elsewhere: dict[str, str]
) -> tuple[str, str | None]:
    """The message for an unknown field and the valid name it most likely meant (if any):
    a foreign-format hint, the closest valid name here, or the closest name that belongs at
    another level of the file."""
    if name in foreign:
        meant = [q for q in re.findall(r"'(\w+)'", foreign[name]) if q in valid]
        return f"unknown field {name!r} — {foreign[name]}", meant[0] if meant else None
    close = difflib.get_close_matches(name, valid, n=1, cutoff=0.6)
    if close:
        return f"unknown field {name!r} — did you mean {close[0]!r}?", close[0]
    close = difflib.get_close_matches(name, list(elsewhere), n=1, cutoff=0.6)
    if close:
        return (
            f"unknown field {name!r} — did you mean {close[0]!r}? (it belongs "
            f"{elsewhere[close[0]]})",
            None,
        )
    return f"unknown field {name!r} (valid fields: {', '.join(valid)})", None


RigidMatrix = Annotated[
    list[list[float]], BeforeValidator(_matrix_shape), AfterValidator(check_rigid_matrix)
]
"""A 4x4 rigid pose, row-major: the shape checked before numeric parsing, rigidity after."""


class StrictModel(BaseModel):
    """Base of every wire camera model: unknown fields are refused, naming the closest valid
    one; the required fields in ``REQUIRED_HINTS`` say how to fill them in when missing."""

    model_config = ConfigDict(extra="forbid")

    FOREIGN_FIELDS: ClassVar[dict[str, str]] = {}
    """Field names of other formats (Blender, COLMAP, nerfstudio) -> what to write instead."""
    ELSEWHERE_FIELDS: ClassVar[dict[str, str]] = {}
    """Valid names at another level of the file -> where they belong (for typo hints)."""
    REQUIRED_HINTS: ClassVar[dict[str, str]] = {}
    """Required field -> how to fill it in (used in the 'missing' message)."""

    @model_validator(mode="before")
    @classmethod
    def _refuse_unknown_and_name_missing(cls, data: Any) -> Any:
        if not isinstance(data, dict):
            return data
        valid = list(cls.model_fields)
        problems, meant = [], set()
        for key in data:
            if key not in cls.model_fields:
                message, guess = _unknown_field_message(
                    str(key), valid, cls.FOREIGN_FIELDS, cls.ELSEWHERE_FIELDS
                )
                problems.append(message)
                meant.add(guess)
        problems += [
            f"missing {name!r}: {hint}"
            for name, hint in cls.REQUIRED_HINTS.items()
            if name not in data and name not in meant
        ]
        if problems:
            raise ValueError("; ".join(problems))
        return data


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


_MATRIX_FOREIGN = {
    "transform_matrix": "did you mean 'matrix'? (Blender/NeRF 'transform_matrix' is an "
    "OpenGL camera-to-world: put it in 'matrix' with convention 'opengl', pose "
    "'camera_to_world')",
    "camera_to_world": "put the 4x4 in 'matrix' and say pose 'camera_to_world'",
    "world_to_camera": "put the 4x4 in 'matrix' and say pose 'world_to_camera'",
    "c2w": "put the 4x4 in 'matrix' and say pose 'camera_to_world'",
    "w2c": "put the 4x4 in 'matrix' and say pose 'world_to_camera'",
    "pose": "'pose' (camera_to_world | world_to_camera) belongs at the top level of the file; "
    "the 4x4 goes in 'matrix'",
    "convention": "'convention' belongs at the top level of the file",
    "file_path": "did you mean 'image'? (the image file name, with its suffix)",
    "fl_x": "did you mean 'fx'?",
    "fl_y": "did you mean 'fy'?",
    "w": "did you mean 'width'?",
    "h": "did you mean 'height'?",
    "K": "give the intrinsics as 'fx', 'fy', 'cx', 'cy' (pixels)",
    "intrinsics": "give the intrinsics as 'fx', 'fy', 'cx', 'cy' (pixels)",
}


class CameraFrame(StrictModel):
    """One image with its pose and pinhole intrinsics (pixels; pixel centres at +0.5)."""

    FOREIGN_FIELDS: ClassVar[dict[str, str]] = _MATRIX_FOREIGN
    ELSEWHERE_FIELDS: ClassVar[dict[str, str]] = {
        "convention": "at the top level of the file",
        "pose": "at the top level of the file",
        "init_box": "at the top level of the file",
    }
    REQUIRED_HINTS: ClassVar[dict[str, str]] = {
        "image": "the image file name inside the scene folder",
        "matrix": "the 4x4 pose, row-major, in the file's 'convention' and 'pose' direction",
    }

    image: str = Field(min_length=1)
    """File name of the image within the upload (relative, no '..')."""
    matrix: RigidMatrix
    """4x4 rigid pose, row-major, in the file's ``convention`` and ``pose`` direction."""
    fx: float = Field(gt=0, allow_inf_nan=False)
    """Focal length along x in pixels."""
    fy: float = Field(gt=0, allow_inf_nan=False)
    """Focal length along y in pixels."""
    cx: float = Field(allow_inf_nan=False)
    """Principal point x in pixels (pixel centres at +0.5; the image centre is width / 2)."""
    cy: float = Field(allow_inf_nan=False)
    """Principal point y in pixels."""
    width: int | None = Field(default=None, gt=0)
    """Image width in pixels; checked against the image when given."""
    height: int | None = Field(default=None, gt=0)
    """Image height in pixels; checked against the image when given."""
    depth: str | None = None
    """Optional depth map file (float ``.npy`` in scene units or 16-bit ``.png``)."""
    depth_scale: float | None = Field(default=None, gt=0, allow_inf_nan=False)
    """Divisor turning integer depth PNG values into scene units (e.g. 1000 for millimetres);
    overrides the file-level ``depth_scale``."""
    mask: str | None = None
    """Optional object mask, an image of the same size (object where its grey value is at
    least half the range, e.g. white on black). A held-out view
    with a mask is scored on the object only: PSNR over the mask with both images composited
    on white, the DTU protocol."""
    split: Split = Split.train
    """Whether the frame is a training or a held-out view."""
    near: float | None = Field(default=None, gt=0, allow_inf_nan=False)
    """Optional nearest depth of the scene seen by this camera (scene units along its optical
    axis, e.g. a row of LLFF ``poses_bounds.npy``); with ``far``, it bounds the region the
    random initialisation fills. Default: the file's ``near``."""
    far: float | None = Field(default=None, gt=0, allow_inf_nan=False)
    """Optional farthest depth of the scene seen by this camera; default: the file's ``far``."""
    rotation_std_deg: float | None = Field(default=None, ge=0, allow_inf_nan=False)
    """Optional uncertainty of this camera's orientation relative to the other cameras (one
    standard deviation, degrees), as estimated from the photos (``sparsesplat cameras`` and
    the service write it). Training refines the poses when a training camera's is at least
    ``POSE_REFINE_MIN_STD_DEG`` of the presets (0.6°); left out: the pose is taken as exact."""

    @model_validator(mode="after")
    def _check_bounds(self) -> CameraFrame:
        check_bounds(self.near, self.far, f"frame {self.image!r}")
        return self

    @field_validator("image")
    @classmethod
    def _check_image(cls, value: str) -> str:
        return _relative_file(value, "image")

    @field_validator("depth")
    @classmethod
    def _check_depth(cls, value: str | None) -> str | None:
        return None if value is None else _relative_file(value, "depth")

    @field_validator("mask")
    @classmethod
    def _check_mask(cls, value: str | None) -> str | None:
        return None if value is None else _relative_file(value, "mask")


class CamerasFile(StrictModel):
    """Contents of ``cameras.json``: the pose convention, then one frame per image."""

    FOREIGN_FIELDS: ClassVar[dict[str, str]] = {
        "camera_angle_x": "give per-frame 'fx'/'fy' in pixels: fx = 0.5 * width / "
        "tan(0.5 * camera_angle_x) (see docs/cameras.md)",
        "transform": "did you mean 'pose'? (camera_to_world | world_to_camera)",
    }
    ELSEWHERE_FIELDS: ClassVar[dict[str, str]] = {
        name: "in each frame"
        for name in (
            "image",
            "matrix",
            "split",
            "width",
            "height",
            "depth",
            "mask",
        )
    }
    REQUIRED_HINTS: ClassVar[dict[str, str]] = {
        "convention": CONVENTION_HINT,
        "pose": POSE_HINT,
        "frames": "the list of images with their 'matrix' and intrinsics",
    }

    convention: AxisConvention
    """Camera axes the matrices use (required: ``opencv`` or ``opengl``)."""
    pose: PoseDirection
    """Direction of every matrix (required: ``camera_to_world`` or ``world_to_camera``)."""
    depth_scale: float = Field(default=1.0, gt=0, allow_inf_nan=False)
    """Divisor turning integer depth PNG values into scene units, for every frame."""
    frames: list[CameraFrame] = Field(min_length=1)
    """The images, in any order."""
    near: float | None = Field(default=None, gt=0, allow_inf_nan=False)
    """Optional nearest depth of the scene from any camera (scene units). The depth priors
    sweep from here and the rasterizer culls Gaussians closer than a fifth of it. Default: the
    frames' own ``near`` when they give one, else the user depth maps, else an estimate from
    where the cameras' optical axes meet (wide on purpose)."""
    far: float | None = Field(default=None, gt=0, allow_inf_nan=False)
    """Optional farthest depth of the scene from any camera (scene units); default as ``near``."""
    init_box: tuple[Vec3, Vec3] | None = None
    """Optional box the scene lies in: its minimum then its maximum corner, world units (e.g.
    DTU's unit sphere or NeRF-synthetic's [-1, 1] cube). Random initialisation draws its
    points here. Default: the space the training cameras see in common between their bounds."""

    @field_validator("init_box")
    @classmethod
    def _check_init_box(cls, value: tuple[Vec3, Vec3] | None) -> tuple[Vec3, Vec3] | None:
        if value is not None:
            low, high = value
            if not all(math.isfinite(v) for v in (*low, *high)):
                raise ValueError("init_box must be finite")
            if not all(lo < hi for lo, hi in zip(low, high, strict=True)):
                raise ValueError(
                    f"init_box: the first corner {list(low)} must be below the second "
                    f"{list(high)} on every axis"
                )
        return value

    @model_validator(mode="after")
    def _check_frames(self) -> CamerasFile:
        check_bounds(self.near, self.far, "the file")
        names = [f.image for f in self.frames]
        duplicates = sorted({n for n in names if names.count(n) > 1})
        if duplicates:
            raise ValueError(f"image listed more than once: {', '.join(duplicates)}")
        n_train = sum(f.split == Split.train for f in self.frames)
        if n_train < 2:
            raise ValueError(f"need at least 2 training views (split 'train'), got {n_train}")
        return self


class PinholeCamera(StrictModel):
    """One camera to render from: explicit pose convention, intrinsics and image size.

    ``convention`` and ``pose`` are required: a silent default is the most common pose bug.
    """

    FOREIGN_FIELDS: ClassVar[dict[str, str]] = {
        k: v for k, v in _MATRIX_FOREIGN.items() if k not in ("pose", "convention")
    }
    REQUIRED_HINTS: ClassVar[dict[str, str]] = {
        "convention": CONVENTION_HINT,
        "pose": POSE_HINT,
        "matrix": "the 4x4 pose, row-major, in 'convention' axes and 'pose' direction",
    }

    convention: AxisConvention
    """Camera axes of ``matrix``: ``opencv`` (+y down, +z forward) or ``opengl`` (+y up,
    +z back)."""
    pose: PoseDirection
    """``camera_to_world`` (the camera's placement) or ``world_to_camera`` (a view matrix)."""
    matrix: RigidMatrix
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

    def world_to_camera_opencv(self) -> list[list[float]]:
        """The pose as the engine uses it: world-to-camera in OpenCV axes (row-major 4x4)."""
        return to_world_to_camera_opencv(self.matrix, self.convention, self.pose)


def to_world_to_camera_opencv(
    matrix: list[list[float]], convention: AxisConvention | str, pose: PoseDirection | str
) -> list[list[float]]:
    """A validated 4x4 in ``convention`` axes and ``pose`` direction -> world-to-camera in
    OpenCV axes (the engine's convention), row-major, pure Python."""
    m = [list(row) for row in matrix]
    if PoseDirection(pose) == PoseDirection.camera_to_world:
        m = rigid_inverse(m)
    if AxisConvention(convention) == AxisConvention.opengl:
        # World-to-camera in OpenGL axes -> OpenCV axes: negate the camera's y and z rows.
        m = [m[0], [-x for x in m[1]], [-x for x in m[2]], m[3]]
    return m


def rigid_inverse(m: list[list[float]]) -> list[list[float]]:
    """Inverse of a rigid 4x4 ``[R t; 0 1]`` as ``[R^T, -R^T t; 0 1]`` (pure Python)."""
    rt = [[m[j][i] for j in range(3)] for i in range(3)]
    t = [-sum(rt[i][k] * m[k][3] for k in range(3)) for i in range(3)]
    return [rt[0] + [t[0]], rt[1] + [t[1]], rt[2] + [t[2]], [0.0, 0.0, 0.0, 1.0]]


def _where(loc: list[Any], data: Any) -> str:
    """``frames[2] (r_2.png).matrix`` for a pydantic error location."""
    where = ""
    for i, part in enumerate(loc):
        if isinstance(part, int):
            where += f"[{part}]"
            frames = data.get("frames") if isinstance(data, dict) else None
            if i == 1 and loc[0] == "frames" and isinstance(frames, list) and part < len(frames):
                frame = frames[part]
                if isinstance(frame, dict) and isinstance(frame.get("image"), str):
                    where += f" ({frame['image']})"
        else:
            where += ("." if where else "") + str(part)
    return where


def describe_validation_error(exc: ValidationError, data: Any = None) -> str:
    """A readable one-problem-per-line text for a cameras ValidationError.

    Each line is ``where: problem``; ``where`` names the frame by index and image file when
    ``data`` (the parsed JSON that failed) is given, e.g. ``frames[2] (r_2.png).matrix``."""
    lines = []
    for err in exc.errors(include_url=False):
        loc = list(err.get("loc", ()))
        msg = str(err.get("msg", ""))
        kind = err.get("type")
        if msg.startswith("Value error, "):
            msg = msg[len("Value error, ") :]
        elif kind == "missing" and loc:
            msg, loc = f"missing {loc[-1]!r}", loc[:-1]
        elif kind == "extra_forbidden" and loc:
            msg, loc = f"unknown field {loc[-1]!r}", loc[:-1]
        elif kind == "enum":
            msg = f"{msg}, got {err.get('input')!r}"
        elif "input" in err and kind not in ("model_type", "list_type", "dict_type"):
            msg = f"{msg} (got {err['input']!r})"
        where = _where(loc, data)
        lines.append(f"{where}: {msg}" if where else msg)
    return "\n".join(lines)


MIN_PHOTOS = 2
"""Fewest photos whose cameras can be estimated (three or more from different places is
better)."""


_INTRINSICS_ORDER = ("fx", "fy", "cx", "cy", "width", "height")
"""The order of :class:`Intrinsics`' positional arguments."""


class Intrinsics(StrictModel):
    """Pinhole intrinsics in pixels (pixel centres at +0.5), and optionally the image size.

    One class for both uses: the lens shared by every photo of an upload without poses (the
    cameras are estimated with it held fixed; a size, when given, must be the photos'), and
    the SDK's lens for building cameras (``client.cameras``: ``look_at``, ``orbit``, ...),
    which needs the size too. Positional arguments work: ``Intrinsics(fx, fy, cx, cy, w, h)``.
    """

    model_config = ConfigDict(extra="forbid", frozen=True)

    REQUIRED_HINTS: ClassVar[dict[str, str]] = {
        "fx": "focal length along x in pixels",
        "fy": "focal length along y in pixels",
        "cx": "principal point x in pixels (the image centre is width / 2)",
        "cy": "principal point y in pixels (the image centre is height / 2)",
    }

    fx: float = Field(gt=0, allow_inf_nan=False)
    """Focal length along x in pixels."""
    fy: float = Field(gt=0, allow_inf_nan=False)
    """Focal length along y in pixels."""
    cx: float = Field(allow_inf_nan=False)
    """Principal point x in pixels."""
    cy: float = Field(allow_inf_nan=False)
    """Principal point y in pixels."""
    width: int | None = Field(default=None, gt=0)
    """Image width in pixels (None: not given)."""
    height: int | None = Field(default=None, gt=0)
    """Image height in pixels (None: not given)."""

    def __init__(self, *args: float | None, **fields: Any) -> None:
        """The fields by name, or the first ones in order: ``Intrinsics(fx, fy, cx, cy, w, h)``.
        (Validation calls this too, with the fields by name.)"""
        if len(args) > len(_INTRINSICS_ORDER):
            raise TypeError(f"Intrinsics takes at most {len(_INTRINSICS_ORDER)} values in order")
        for name, value in zip(_INTRINSICS_ORDER, args, strict=False):
            if name in fields:
                raise TypeError(f"Intrinsics got {name!r} both in order and by name")
            fields[name] = value
        # BaseModel's own __init__ (it validates), past the field-typed one type checkers
        # synthesize for StrictModel.
        BaseModel.__init__(self, **fields)

    @classmethod
    def from_fov(
        cls, width: int, height: int, fov_x_deg: float, fov_y_deg: float | None = None
    ) -> Intrinsics:
        """Centred intrinsics from a horizontal field of view (and a vertical one, else square
        pixels)."""
        fx = 0.5 * width / math.tan(math.radians(fov_x_deg) / 2)
        fy = fx if fov_y_deg is None else 0.5 * height / math.tan(math.radians(fov_y_deg) / 2)
        return cls(fx, fy, width / 2, height / 2, int(width), int(height))

    @classmethod
    def centred(
        cls,
        fx: float,
        width: int,
        height: int,
        fy: float | None = None,
        cx: float | None = None,
        cy: float | None = None,
    ) -> Intrinsics:
        """The lens of ``width`` x ``height`` images with what is not given by default:
        ``fy`` equal to ``fx`` (square pixels), ``cx, cy`` at the image centre."""
        return cls(
            fx,
            fx if fy is None else fy,
            width / 2 if cx is None else cx,
            height / 2 if cy is None else cy,
            width,
            height,
        )

    @classmethod
    def of(cls, camera: PinholeCamera) -> Intrinsics:
        """The intrinsics (and size) of ``camera``."""
        return cls(camera.fx, camera.fy, camera.cx, camera.cy, camera.width, camera.height)

    def scaled(self, factor: float) -> Intrinsics:
        """The same lens for an image resized by ``factor`` (0.5: half the size)."""
        return Intrinsics(
            self.fx * factor,
            self.fy * factor,
            self.cx * factor,
            self.cy * factor,
            None if self.width is None else max(1, round(self.width * factor)),
            None if self.height is None else max(1, round(self.height * factor)),
        )

    @property
    def size(self) -> tuple[int, int] | None:
        """``(width, height)``, or None when either is not given."""
        if self.width is None or self.height is None:
            return None
        return self.width, self.height

    def fields(self) -> dict[str, Any]:
        """As PinholeCamera keyword arguments; ValueError without the image size."""
        if self.size is None:
            raise ValueError("these intrinsics have no image size: give width and height")
        return {
            "fx": float(self.fx),
            "fy": float(self.fy),
            "cx": float(self.cx),
            "cy": float(self.cy),
            "width": self.size[0],
            "height": self.size[1],
        }
