"""Camera helpers users expect, in pure Python (NumPy arrays are accepted, never required).

Every helper returns :class:`~sparsesplat.api.cameras.PinholeCamera`, the one camera schema
the service accepts; the cameras it builds are ``opencv`` axes, ``camera_to_world`` (the
camera's placement in the world: +x right, +y down, +z forward)::

    from sparsesplat.client import cameras as cams

    k = cams.Intrinsics.from_fov(400, 300, fov_x_deg=50)
    a = cams.look_at(eye=(0, -4, 1), target=(0, 0, 0), up=(0, 0, 1), intrinsics=k)
    b = cams.from_matrix(c2w_4x4, convention="opengl", pose="camera_to_world", intrinsics=k)
    path = cams.interpolate(a, b, 30)                      # 30 poses, rotation slerped
    ring = cams.orbit((0, 0, 0), radius=4, n=60, up=(0, 0, 1), elevation_deg=20, intrinsics=k)
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import Any

from sparsesplat.api.cameras import (
    AxisConvention,
    Intrinsics,
    PinholeCamera,
    PoseDirection,
    rigid_inverse,
)
from sparsesplat.client.errors import InvalidInput

Vec3 = tuple[float, float, float]
Matrix = list[list[float]]

__all__ = [
    "Intrinsics",
    "camera_to_world_opencv",
    "center_of_interest",
    "from_matrices",
    "from_matrix",
    "interpolate",
    "interpolate_pair",
    "look_at",
    "orbit",
    "orbit_around",
    "with_intrinsics",
]


def _lens(intrinsics: Intrinsics) -> dict[str, Any]:
    """``intrinsics`` as PinholeCamera keyword arguments; InvalidInput without its size."""
    try:
        return intrinsics.fields()
    except ValueError as exc:
        raise InvalidInput(f"intrinsics: {exc}") from exc


# ---------------------------------------------------------------- small linear algebra


def _matrix(value: Any, what: str = "matrix") -> Matrix:
    """A 4x4 (or 3x4, completed with [0, 0, 0, 1]) of floats from lists or a NumPy array."""
    if hasattr(value, "tolist"):
        value = value.tolist()
    try:
        rows = [[float(x) for x in row] for row in value]
    except (TypeError, ValueError) as exc:
        raise InvalidInput(f"{what}: expected a 4x4 matrix of numbers ({exc})") from exc
    if len(rows) == 3 and all(len(r) == 4 for r in rows):
        rows.append([0.0, 0.0, 0.0, 1.0])
    if len(rows) != 4 or any(len(r) != 4 for r in rows):
        raise InvalidInput(f"{what}: expected a 4x4 matrix, got {len(rows)} rows")
    return rows


def _vec(value: Any, what: str) -> Vec3:
    if hasattr(value, "tolist"):
        value = value.tolist()
    try:
        x, y, z = (float(v) for v in value)
    except (TypeError, ValueError) as exc:
        raise InvalidInput(f"{what}: expected 3 numbers ({exc})") from exc
    return (x, y, z)


def _sub(a: Vec3, b: Vec3) -> Vec3:
    return (a[0] - b[0], a[1] - b[1], a[2] - b[2])


def _add(a: Vec3, b: Vec3) -> Vec3:
    return (a[0] + b[0], a[1] + b[1], a[2] + b[2])


def _mul(a: Vec3, s: float) -> Vec3:
    return (a[0] * s, a[1] * s, a[2] * s)


def _dot(a: Vec3, b: Vec3) -> float:
    return a[0] * b[0] + a[1] * b[1] + a[2] * b[2]


def _cross(a: Vec3, b: Vec3) -> Vec3:
    return (a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0])


def _norm(a: Vec3) -> float:
    return math.sqrt(_dot(a, a))


def _unit(a: Vec3, what: str) -> Vec3:
    n = _norm(a)
    if n < 1e-12:
        raise InvalidInput(f"{what} has zero length")
    return _mul(a, 1.0 / n)


def _pose(right: Vec3, down: Vec3, forward: Vec3, centre: Vec3) -> Matrix:
    """OpenCV camera-to-world from the camera axes (world coordinates) and its centre."""
    return [
        [right[0], down[0], forward[0], centre[0]],
        [right[1], down[1], forward[1], centre[1]],
        [right[2], down[2], forward[2], centre[2]],
        [0.0, 0.0, 0.0, 1.0],
    ]


def _camera(c2w_opencv: Matrix, intrinsics: Intrinsics) -> PinholeCamera:
    return PinholeCamera(
        convention=AxisConvention.opencv,
        pose=PoseDirection.camera_to_world,
        matrix=c2w_opencv,
        **_lens(intrinsics),
    )


# ---------------------------------------------------------------- constructors


def from_matrix(
    matrix: Any,
    *,
    convention: AxisConvention | str,
    pose: PoseDirection | str,
    intrinsics: Intrinsics | None = None,
    fx: float | None = None,
    fy: float | None = None,
    cx: float | None = None,
    cy: float | None = None,
    width: int | None = None,
    height: int | None = None,
) -> PinholeCamera:
    """A camera from a 4x4 pose (lists or a NumPy array) in either convention and direction.

    ``convention`` (``opencv`` | ``opengl``) and ``pose`` (``camera_to_world`` |
    ``world_to_camera``) are required: guessing them is the most common pose bug. Give the
    lens as ``intrinsics`` or as ``fx, fy, cx, cy, width, height`` (``fy`` defaults to ``fx``,
    ``cx, cy`` to the image centre)."""
    if intrinsics is None:
        if fx is None or width is None or height is None:
            raise InvalidInput("give 'intrinsics' or at least fx, width and height")
        intrinsics = Intrinsics.centred(fx, width, height, fy, cx, cy)
    return PinholeCamera(
        convention=AxisConvention(convention),
        pose=PoseDirection(pose),
        matrix=_matrix(matrix),
        **_lens(intrinsics),
    )


def from_matrices(
    matrices: Any,
    *,
    convention: AxisConvention | str,
    pose: PoseDirection | str,
    intrinsics: Intrinsics | Sequence[Intrinsics],
) -> list[PinholeCamera]:
    """:func:`from_matrix` for an (N, 4, 4) array or a list of 4x4s, one lens or one each."""
    items = list(matrices)
    lenses = [intrinsics] * len(items) if isinstance(intrinsics, Intrinsics) else list(intrinsics)
    if len(lenses) != len(items):
        raise InvalidInput(f"{len(items)} matrices but {len(lenses)} intrinsics")
    return [
        from_matrix(m, convention=convention, pose=pose, intrinsics=k)
        for m, k in zip(items, lenses, strict=True)
    ]


def camera_to_world_opencv(camera: PinholeCamera) -> Matrix:
    """``camera``'s pose as an OpenCV camera-to-world 4x4 (whatever it was given in)."""
    m = [list(row) for row in camera.matrix]
    if camera.pose == PoseDirection.world_to_camera:
        m = rigid_inverse(m)
    if camera.convention == AxisConvention.opengl:
        # Camera-to-world: flip the camera's y and z axes (the matrix's columns 1 and 2).
        m = [[r[0], -r[1], -r[2], r[3]] for r in m]
    return m


def look_at(
    eye: Any,
    target: Any,
    up: Any = (0.0, 0.0, 1.0),
    *,
    intrinsics: Intrinsics,
) -> PinholeCamera:
    """A camera at ``eye`` looking at ``target`` with ``up`` pointing up in the image.

    ``up`` is a world direction (default +z, Blender's up; LLFF/COLMAP scenes are often -y);
    it must not be parallel to the viewing direction."""
    eye_v, target_v, up_v = _vec(eye, "eye"), _vec(target, "target"), _vec(up, "up")
    forward = _unit(_sub(target_v, eye_v), "target - eye")
    right = _cross(forward, _unit(up_v, "up"))
    if _norm(right) < 1e-6:
        raise InvalidInput("look_at: 'up' is parallel to the viewing direction; pick another up")
    right = _unit(right, "right")
    down = _cross(forward, right)
    return _camera(_pose(right, down, forward, eye_v), intrinsics)


def orbit(
    center: Any,
    radius: float,
    n: int,
    *,
    intrinsics: Intrinsics,
    up: Any = (0.0, 0.0, 1.0),
    elevation_deg: float = 20.0,
    start_deg: float = 0.0,
    arc_deg: float = 360.0,
) -> list[PinholeCamera]:
    """``n`` cameras on a circle of ``radius`` around ``center``, all looking at it.

    The circle lies ``elevation_deg`` above the plane through ``center`` perpendicular to
    ``up``; it starts at ``start_deg`` and covers ``arc_deg`` (360: a closed loop without
    repeating the first pose)."""
    if n < 1:
        raise InvalidInput("orbit: n must be at least 1")
    c, u = _vec(center, "center"), _unit(_vec(up, "up"), "up")
    # Two directions spanning the plane perpendicular to up.
    helper: Vec3 = (1.0, 0.0, 0.0) if abs(u[0]) < 0.9 else (0.0, 1.0, 0.0)
    e1 = _unit(_cross(u, helper), "orbit axis")
    e2 = _cross(u, e1)
    elevation = math.radians(elevation_deg)
    step = arc_deg / n if abs(arc_deg - 360.0) < 1e-9 else arc_deg / max(n - 1, 1)
    cameras = []
    for i in range(n):
        a = math.radians(start_deg + i * step)
        direction = _add(
            _mul(_add(_mul(e1, math.cos(a)), _mul(e2, math.sin(a))), math.cos(elevation)),
            _mul(u, math.sin(elevation)),
        )
        cameras.append(look_at(_add(c, _mul(direction, radius)), c, u, intrinsics=intrinsics))
    return cameras


def center_of_interest(cameras: Sequence[PinholeCamera]) -> Vec3:
    """The point nearest (least squares) to every camera's optical axis: what they look at."""
    a = [[0.0] * 3 for _ in range(3)]
    b = [0.0, 0.0, 0.0]
    for cam in cameras:
        m = camera_to_world_opencv(cam)
        d = _unit((m[0][2], m[1][2], m[2][2]), "optical axis")
        p = (m[0][3], m[1][3], m[2][3])
        for i in range(3):
            for j in range(3):
                proj = (1.0 if i == j else 0.0) - d[i] * d[j]
                a[i][j] += proj
                b[i] += proj * p[j]
    solved = _solve3(a, b)
    if solved is None:  # parallel axes (a forward-facing rig): a point ahead of the cameras
        centres = [_centre(cam) for cam in cameras]
        mean = _mul(_sum(centres), 1.0 / len(centres))
        forward = _unit(_sum([_axis(cam, 2) for cam in cameras]), "mean view direction")
        return _add(mean, forward)
    return solved


def orbit_around(
    cameras: Sequence[PinholeCamera],
    n: int,
    *,
    intrinsics: Intrinsics | None = None,
    radius_scale: float = 1.0,
    arc_deg: float = 360.0,
    elevation_deg: float | None = None,
) -> list[PinholeCamera]:
    """An orbit fitted to a set of cameras (e.g. a model's training views): around the point
    they look at, with their mean up direction, distance and elevation, starting at the first
    camera; the lens of the first camera unless ``intrinsics`` is given. For a forward-facing
    capture ask for a small ``arc_deg`` (e.g. 30)."""
    if not cameras:
        raise InvalidInput("orbit_around: no cameras")
    center = center_of_interest(cameras)
    up = _unit(_mul(_sum([_axis(cam, 1) for cam in cameras]), -1.0), "mean up direction")
    offsets = [_sub(_centre(cam), center) for cam in cameras]
    radius = sum(_norm(o) for o in offsets) / len(offsets) * radius_scale
    if elevation_deg is None:
        elevation_deg = math.degrees(
            sum(math.asin(max(-1.0, min(1.0, _dot(_unit(o, "offset"), up)))) for o in offsets)
            / len(offsets)
        )
    first = offsets[0]
    flat = _sub(first, _mul(up, _dot(first, up)))
    helper: Vec3 = (1.0, 0.0, 0.0) if abs(up[0]) < 0.9 else (0.0, 1.0, 0.0)
    e1 = _unit(_cross(up, helper), "orbit axis")
    e2 = _cross(up, e1)
    start = math.degrees(math.atan2(_dot(flat, e2), _dot(flat, e1))) if _norm(flat) > 1e-9 else 0
    if abs(arc_deg - 360.0) > 1e-9:
        start -= arc_deg / 2
    return orbit(
        center,
        radius,
        n,
        intrinsics=intrinsics or Intrinsics.of(cameras[0]),
        up=up,
        elevation_deg=elevation_deg,
        start_deg=start,
        arc_deg=arc_deg,
    )


# ---------------------------------------------------------------- interpolation


def interpolate_pair(a: PinholeCamera, b: PinholeCamera, t: float) -> PinholeCamera:
    """The pose a fraction ``t`` of the way from ``a`` to ``b``: rotation by slerp, centre
    and intrinsics linearly; image size of ``a``. The result is OpenCV camera-to-world."""
    ma, mb = camera_to_world_opencv(a), camera_to_world_opencv(b)
    qa, qb = _quaternion(ma), _quaternion(mb)
    rot = _rotation(_slerp(qa, qb, t))
    centre = _add(_mul(_centre(a), 1 - t), _mul(_centre(b), t))
    matrix = [rot[0] + [centre[0]], rot[1] + [centre[1]], rot[2] + [centre[2]], [0.0, 0, 0, 1]]
    k = Intrinsics(
        a.fx + (b.fx - a.fx) * t,
        a.fy + (b.fy - a.fy) * t,
        a.cx + (b.cx - a.cx) * t,
        a.cy + (b.cy - a.cy) * t,
        a.width,
        a.height,
    )
    return _camera(matrix, k)


def interpolate(a: PinholeCamera, b: PinholeCamera, n: int) -> list[PinholeCamera]:
    """``n`` poses from ``a`` to ``b`` inclusive (slerp for the rotation, see
    :func:`interpolate_pair`)."""
    if n < 2:
        raise InvalidInput("interpolate: n must be at least 2 (both ends included)")
    return [interpolate_pair(a, b, i / (n - 1)) for i in range(n)]


def _centre(cam: PinholeCamera) -> Vec3:
    m = camera_to_world_opencv(cam)
    return (m[0][3], m[1][3], m[2][3])


def _axis(cam: PinholeCamera, column: int) -> Vec3:
    m = camera_to_world_opencv(cam)
    return (m[0][column], m[1][column], m[2][column])


def _sum(vectors: Sequence[Vec3]) -> Vec3:
    out: Vec3 = (0.0, 0.0, 0.0)
    for v in vectors:
        out = _add(out, v)
    return out


def _solve3(a: list[list[float]], b: list[float]) -> Vec3 | None:
    """Solve a 3x3 system by Cramer's rule; None when (nearly) singular."""

    def det(m: list[list[float]]) -> float:
        return (
            m[0][0] * (m[1][1] * m[2][2] - m[1][2] * m[2][1])
            - m[0][1] * (m[1][0] * m[2][2] - m[1][2] * m[2][0])
            + m[0][2] * (m[1][0] * m[2][1] - m[1][1] * m[2][0])
        )

    d = det(a)
    scale = max(abs(x) for row in a for x in row) or 1.0
    if abs(d) < 1e-6 * scale**3:
        return None
    out = []
    for col in range(3):
        m = [row[:] for row in a]
        for r in range(3):
            m[r][col] = b[r]
        out.append(det(m) / d)
    return (out[0], out[1], out[2])


Quaternion = tuple[float, float, float, float]


def _quaternion(m: Matrix) -> Quaternion:
    """Unit quaternion (w, x, y, z) of the 3x3 rotation block of ``m``."""
    trace = m[0][0] + m[1][1] + m[2][2]
    if trace > 0:
        s = 2.0 * math.sqrt(trace + 1.0)
        q = (0.25 * s, (m[2][1] - m[1][2]) / s, (m[0][2] - m[2][0]) / s, (m[1][0] - m[0][1]) / s)
    elif m[0][0] > m[1][1] and m[0][0] > m[2][2]:
        s = 2.0 * math.sqrt(1.0 + m[0][0] - m[1][1] - m[2][2])
        q = ((m[2][1] - m[1][2]) / s, 0.25 * s, (m[0][1] + m[1][0]) / s, (m[0][2] + m[2][0]) / s)
    elif m[1][1] > m[2][2]:
        s = 2.0 * math.sqrt(1.0 + m[1][1] - m[0][0] - m[2][2])
        q = ((m[0][2] - m[2][0]) / s, (m[0][1] + m[1][0]) / s, 0.25 * s, (m[1][2] + m[2][1]) / s)
    else:
        s = 2.0 * math.sqrt(1.0 + m[2][2] - m[0][0] - m[1][1])
        q = ((m[1][0] - m[0][1]) / s, (m[0][2] + m[2][0]) / s, (m[1][2] + m[2][1]) / s, 0.25 * s)
    n = math.sqrt(sum(c * c for c in q))
    return (q[0] / n, q[1] / n, q[2] / n, q[3] / n)


def _slerp(a: Quaternion, b: Quaternion, t: float) -> Quaternion:
    dot = sum(x * y for x, y in zip(a, b, strict=True))
    if dot < 0:  # take the short way round
        b, dot = (-b[0], -b[1], -b[2], -b[3]), -dot
    if dot > 0.9995:
        q = tuple(x + (y - x) * t for x, y in zip(a, b, strict=True))
    else:
        theta = math.acos(dot)
        sa, sb = math.sin((1 - t) * theta), math.sin(t * theta)
        q = tuple((x * sa + y * sb) / math.sin(theta) for x, y in zip(a, b, strict=True))
    n = math.sqrt(sum(c * c for c in q))
    return (q[0] / n, q[1] / n, q[2] / n, q[3] / n)


def _rotation(q: Quaternion) -> list[list[float]]:
    w, x, y, z = q
    return [
        [1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
        [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
        [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)],
    ]


def with_intrinsics(camera: PinholeCamera, intrinsics: Intrinsics) -> PinholeCamera:
    """``camera`` with another lens / image size (pose unchanged)."""
    return camera.model_copy(update=_lens(intrinsics))
