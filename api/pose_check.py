"""Does ``cameras.json`` read the matrices the way they were written? Geometry at upload.

A matrix read with the wrong ``convention`` (opencv vs opengl) or the wrong ``pose``
(camera_to_world vs world_to_camera) still validates: it is a rigid 4x4 either way. What gives
it away is the arrangement of the training cameras it produces:

- read with the other convention, inward-looking cameras face away from each other and their
  frusta share nothing;
- a camera-to-world matrix read as world-to-camera (or the reverse) puts every camera of an
  orbit at one point (``-R^T t`` has the orbit's radius in camera axes for each of them).

:func:`check_pose_reading` scores the reading the file names and the three others by how much
of each training camera's frustum another training camera sees, and refuses the file (a
:class:`PoseReadingError` naming the likely fix) when the named reading shares nothing, or
puts every camera at one point, while another reading gives a sound layout. Ambiguous cases
(a forward-facing capture looks plausible under every reading) pass: training finds those and
warns on the job. Pure numpy, no torch: the service checks uploads without loading the engine.
"""

from __future__ import annotations

import itertools
from dataclasses import dataclass

import numpy as np

from sparsesplat.api.cameras import (
    AxisConvention,
    CamerasFile,
    PoseDirection,
    Split,
    to_world_to_camera_opencv,
)

MIN_SHARED = 0.02
"""A reading whose training frusta share less than this fraction is implausible: some camera
must see what another sees for a scene to be reconstructed."""
SOUND_SHARED = 0.10
"""Another reading must share at least this much to be named as the likely fix."""
COINCIDENT = 1e-3
"""Camera centres closer than this fraction of the matrices' own translation scale are one
point (no parallax: nothing can be triangulated)."""
_GRID = 8
"""Pixels per image side sampled in each frustum."""
_DEPTHS = 16
"""Depths sampled along each pixel's ray (log-uniform between the bounds)."""


class PoseReadingError(ValueError):
    """The matrices look like they were written in another convention or direction than the
    file says; the message names the likely fix."""


@dataclass(frozen=True)
class Reading:
    """One way of reading the matrices and how plausible a layout it gives."""

    convention: AxisConvention
    """The axis convention tried."""
    pose: PoseDirection
    """The matrix direction tried."""
    shared: float
    """Mean fraction of each training camera's rays that another training camera sees at
    some depth between the bounds (the file's, else 0.05x to 20x the camera spacing)."""
    coincident: bool
    """Whether every training camera sits at one point under this reading."""

    @property
    def sound(self) -> bool:
        """Whether this reading gives a layout that can be trained."""
        return not self.coincident and self.shared >= MIN_SHARED


def _intrinsics(frame: object) -> tuple[float, float, float, float, float, float]:
    fx, fy, cx, cy = (float(getattr(frame, k)) for k in ("fx", "fy", "cx", "cy"))
    # Without a stored size the principal point is the image centre (cx = width / 2).
    width = float(getattr(frame, "width", None) or 2.0 * cx)
    height = float(getattr(frame, "height", None) or 2.0 * cy)
    return fx, fy, cx, cy, max(width, 1.0), max(height, 1.0)


def assess(cameras: CamerasFile, convention: AxisConvention, pose: PoseDirection) -> Reading:
    """How plausible the training cameras' layout is when read with ``convention``/``pose``."""
    train = [f for f in cameras.frames if f.split == Split.train]
    w2c = np.array(
        [to_world_to_camera_opencv(f.matrix, convention, pose) for f in train], dtype=np.float64
    )
    rot, trans = w2c[:, :3, :3], w2c[:, :3, 3]
    centres = -np.einsum("nji,nj->ni", rot, trans)
    scale = float(np.linalg.norm(np.array([f.matrix for f in train])[:, :3, 3], axis=1).max())
    gaps = [float(np.linalg.norm(a - b)) for a, b in itertools.combinations(centres, 2)]
    spread = float(np.median(gaps))
    if spread <= COINCIDENT * max(scale, 1e-9):
        return Reading(convention, pose, 0.0, True)
    near, far = cameras.near or 0.05 * spread, cameras.far or 20.0 * spread
    shared = []
    for i, frame in enumerate(train):
        fx, fy, cx, cy, width, height = _intrinsics(frame)
        u = (np.arange(_GRID) + 0.5) / _GRID * width
        v = (np.arange(_GRID) + 0.5) / _GRID * height
        depths = np.geomspace(near, far, _DEPTHS)
        uu, vv, zz = np.meshgrid(u, v, depths, indexing="ij")
        local = np.stack([(uu - cx) / fx * zz, (vv - cy) / fy * zz, zz], -1).reshape(-1, 3)
        world = (local - trans[i]) @ rot[i]  # R^T (x - t), row vectors
        seen = np.zeros(len(world), dtype=bool)
        for j, other in enumerate(train):
            if j == i:
                continue
            ofx, ofy, ocx, ocy, owidth, oheight = _intrinsics(other)
            cam = world @ rot[j].T + trans[j]
            z = cam[:, 2]
            with np.errstate(divide="ignore", invalid="ignore"):
                px = ofx * cam[:, 0] / z + ocx
                py = ofy * cam[:, 1] / z + ocy
            seen |= (z > 0) & (px >= 0) & (px < owidth) & (py >= 0) & (py < oheight)
        # A ray counts as shared when another camera sees it at some depth.
        shared.append(float(seen.reshape(_GRID * _GRID, _DEPTHS).any(axis=1).mean()))
    return Reading(convention, pose, float(np.mean(shared)), False)


def _other_convention(value: AxisConvention) -> AxisConvention:
    return AxisConvention.opengl if value == AxisConvention.opencv else AxisConvention.opencv


def _other_pose(value: PoseDirection) -> PoseDirection:
    if value == PoseDirection.camera_to_world:
        return PoseDirection.world_to_camera
    return PoseDirection.camera_to_world


def _describe(reading: Reading) -> str:
    if reading.coincident:
        return "every training camera sits at one point (no parallax)"
    return (
        "the training cameras face away from each other "
        f"({reading.shared:.0%} of one's rays seen by another)"
    )


def check_pose_reading(cameras: CamerasFile) -> Reading:
    """The named reading's assessment; PoseReadingError when it is implausible and another
    reading of the same matrices is sound (the message names the change to make)."""
    given = assess(cameras, cameras.convention, cameras.pose)
    if given.sound:
        _check_box_in_front(cameras)
        return given
    others = [
        assess(cameras, convention, pose)
        for convention, pose in (
            (_other_convention(cameras.convention), cameras.pose),
            (cameras.convention, _other_pose(cameras.pose)),
            (_other_convention(cameras.convention), _other_pose(cameras.pose)),
        )
    ]
    best = max(others, key=lambda r: (not r.coincident, r.shared))
    read_as = f"read with convention {given.convention.value!r} and pose {given.pose.value!r}"
    if best.sound and best.shared >= SOUND_SHARED:
        changes = []
        if best.convention != given.convention:
            changes.append(f'"convention": "{best.convention.value}"')
        if best.pose != given.pose:
            changes.append(f'"pose": "{best.pose.value}"')
        raise PoseReadingError(
            f"cameras.json: {read_as}, {_describe(given)}; read with convention "
            f"{best.convention.value!r} and pose {best.pose.value!r} they see a common region "
            f"({best.shared:.0%} shared). The matrices were likely written that way: say "
            f"{' and '.join(changes)} (docs/cameras.md)"
        )
    if given.coincident:
        raise PoseReadingError(
            f"cameras.json: {read_as}, {_describe(given)}, and no other reading of the "
            "matrices does better: check the 'matrix' of each frame"
        )
    return given


def _check_box_in_front(cameras: CamerasFile) -> None:
    """PoseReadingError when the file's ``init_box`` lies behind every training camera."""
    if cameras.init_box is None:
        return
    low, high = (np.array(corner, dtype=np.float64) for corner in cameras.init_box)
    centre = 0.5 * (low + high)
    train = [f for f in cameras.frames if f.split == Split.train]
    depths = [
        (np.array(to_world_to_camera_opencv(f.matrix, cameras.convention, cameras.pose))
         @ np.append(centre, 1.0))[2]
        for f in train
    ]  # fmt: skip
    if max(depths) < 0:
        raise PoseReadingError(
            f"cameras.json: the centre of 'init_box' {centre.round(3).tolist()} lies behind "
            "every training camera: the scene must be in front of the cameras. Check "
            "'convention' (opencv: +z forward; opengl: +z back) and 'pose', or the box"
        )
