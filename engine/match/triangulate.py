"""The matched start: matches + known cameras -> coloured 3D points with an initial scale.

A pure function of arrays (no trainer, no files): the tracks of :mod:`.tracks` are
triangulated by DLT over every photo that sees them (in normalised image coordinates), refined
by a few Gauss-Newton steps on the reprojection error, and kept when they lie in front of every
observing camera, reproject within ``max_error_px`` in every photo and were seen under a
triangulation angle of at least ``min_angle_deg`` (a point seen along almost one ray has no
depth). Colour is the mean of the photos' bilinear samples at the observations; the scale is
the trainer's own k-nearest-neighbour rule (``engine.gaussians.knn_log_scales``).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np
import torch
from torch import Tensor

from sparsesplat.engine.camera import Camera
from sparsesplat.engine.gaussians import knn_log_scales
from sparsesplat.engine.match.errors import MatchError
from sparsesplat.engine.match.geometry import PinholeArrays
from sparsesplat.engine.match.images import as_float_rgb
from sparsesplat.engine.match.result import MatchSet
from sparsesplat.engine.match.tracks import Tracks, build_tracks


@dataclass(frozen=True)
class TriangulationSettings:
    """The filters of the matched start."""

    max_error_px: float = 2.0
    """Largest reprojection error (pixels) a point may have in any photo that sees it."""
    min_angle_deg: float = 1.0
    """Smallest triangulation angle (degrees): the widest angle between two of a point's
    viewing rays. Its depth error grows as 1 / angle."""
    refine_iterations: int = 5
    """Gauss-Newton steps on the reprojection error after the DLT (0: the DLT alone)."""
    neighbours: int = 3
    """The scale is the RMS distance to this many nearest points (the trainer's rule)."""

    def __post_init__(self) -> None:
        if not self.max_error_px > 0:
            raise MatchError(f"max_error_px must be > 0, got {self.max_error_px}")
        if not 0 <= self.min_angle_deg < 90:
            raise MatchError(f"min_angle_deg must be in [0, 90), got {self.min_angle_deg}")
        if self.refine_iterations < 0 or self.neighbours < 1:
            raise MatchError("refine_iterations must be >= 0 and neighbours >= 1")


@dataclass
class Observations:
    """The kept points' observations, in flat arrays (one row per point and photo)."""

    point: np.ndarray
    """(O,) int64 index of the observed point in :class:`MatchedPoints`."""
    view: np.ndarray
    """(O,) int64 photo index."""
    xy: np.ndarray
    """(O, 2) float32 pixel coordinates (pixel centres at +0.5, the engine's convention)."""

    def in_view(self, view: int) -> tuple[np.ndarray, np.ndarray]:
        """(point indices (K,), pixel coordinates (K, 2)) of the observations in ``view``."""
        rows = self.view == view
        return self.point[rows], self.xy[rows]


@dataclass
class MatchedPoints:
    """The matched start: one row per kept point."""

    points: np.ndarray
    """(N, 3) float32 world positions."""
    colours: np.ndarray
    """(N, 3) float32 RGB in [0, 1]."""
    scales: np.ndarray
    """(N,) float32 initial Gaussian scale (world units)."""
    errors: np.ndarray
    """(N,) float32 largest reprojection error over the observing photos (pixels)."""
    angles: np.ndarray
    """(N,) float32 triangulation angle (degrees)."""
    views: np.ndarray
    """(N,) int32 number of photos observing the point."""
    observations: Observations
    """Where each kept point was seen: one row per (point, photo)."""
    counts: dict[str, int] = field(default_factory=dict)
    """How many tracks each step kept or dropped: 'tracks', 'conflicts', 'behind',
    'error', 'angle', 'kept'."""


def _cameras(cameras: Sequence[Camera | PinholeArrays]) -> list[PinholeArrays]:
    return [c if isinstance(c, PinholeArrays) else PinholeArrays.of(c) for c in cameras]


def _normalised(tracks: Tracks, cams: list[PinholeArrays]) -> np.ndarray:
    """(O, 2) observations in normalised image coordinates K^-1 x."""
    kinv = np.stack([np.linalg.inv(c.K) for c in cams])[tracks.view]
    h = np.concatenate([tracks.xy, np.ones((len(tracks.xy), 1))], axis=1)
    n = np.einsum("oij,oj->oi", kinv, h)
    return n[:, :2] / n[:, 2:3]


def dlt(tracks: Tracks, cams: Sequence[PinholeArrays]) -> tuple[np.ndarray, np.ndarray]:
    """Linear triangulation of every track: (T, 3) float64 points and (T,) bool 'finite'
    (False where the solution lies at infinity)."""
    cams = list(cams)
    norm = _normalised(tracks, cams)
    proj = np.stack([c.world_to_camera[:3, :] for c in cams])[tracks.view]  # (O, 3, 4)
    rows = np.concatenate(
        [
            norm[:, 0:1] * proj[:, 2] - proj[:, 0],
            norm[:, 1:2] * proj[:, 2] - proj[:, 1],
        ],
        axis=1,
    ).reshape(-1, 2, 4)
    out = np.full((tracks.count, 3), np.nan)
    lengths = tracks.lengths()
    starts = np.concatenate([[0], np.cumsum(lengths)])
    for length in np.unique(lengths):
        ids = np.nonzero(lengths == length)[0]
        obs = starts[ids][:, None] + np.arange(length)[None]  # (T_L, L)
        a = rows[obs].reshape(len(ids), 2 * length, 4)
        # Scale each system so the SVD is well conditioned whatever the world units.
        a = a / np.maximum(np.linalg.norm(a, axis=2, keepdims=True), 1e-300)
        h = np.linalg.svd(a)[2][:, -1]
        w = h[:, 3]
        ok = np.abs(w) > 1e-12 * np.linalg.norm(h[:, :3], axis=1)
        out[ids[ok]] = h[ok, :3] / w[ok, None]
    finite = np.isfinite(out).all(axis=1)
    return out, finite


def reprojection(
    points: np.ndarray, tracks: Tracks, cams: Sequence[PinholeArrays]
) -> tuple[np.ndarray, np.ndarray]:
    """Per observation: the pixel error of its track's point and the point's depth z in the
    observing camera."""
    cams = list(cams)
    w2c = np.stack([c.world_to_camera for c in cams])[tracks.view]
    k = np.stack([c.K for c in cams])[tracks.view]
    x = points[tracks.track]
    q = np.einsum("oij,oj->oi", w2c[:, :3, :3], x) + w2c[:, :3, 3]
    z = q[:, 2]
    safe = np.where(np.abs(z) > 1e-300, z, 1e-300)
    uv = np.einsum("oij,oj->oi", k[:, :2, :2], q[:, :2] / safe[:, None]) + k[:, :2, 2]
    return np.linalg.norm(uv - tracks.xy, axis=1), z


def refine(
    points: np.ndarray, tracks: Tracks, cams: Sequence[PinholeArrays], iterations: int
) -> np.ndarray:
    """Gauss-Newton on the summed squared reprojection error of each track's point, cameras
    fixed; a step that does not lower a point's error is not taken."""
    cams = list(cams)
    w2c = np.stack([c.world_to_camera for c in cams])[tracks.view]
    k2 = np.stack([c.K[:2, :2] for c in cams])[tracks.view]
    rot, trans = w2c[:, :3, :3], w2c[:, :3, 3]
    x = points.copy()

    def cost(pts: np.ndarray) -> np.ndarray:
        err, _ = reprojection(pts, tracks, cams)
        return np.bincount(tracks.track, err * err, minlength=tracks.count)

    current = cost(x)
    for _ in range(iterations):
        q = np.einsum("oij,oj->oi", rot, x[tracks.track]) + trans
        z = np.where(np.abs(q[:, 2]) > 1e-12, q[:, 2], 1e-12)
        uv = np.einsum("oij,oj->oi", k2, q[:, :2] / z[:, None])
        k_full = np.stack([c.K for c in cams])[tracks.view]
        r = uv + k_full[:, :2, 2] - tracks.xy  # (O, 2) residuals
        dproj = np.zeros((len(z), 2, 3))
        dproj[:, 0, 0] = 1 / z
        dproj[:, 1, 1] = 1 / z
        dproj[:, :, 2] = -q[:, :2] / (z * z)[:, None]
        jac = k2 @ dproj @ rot  # (O, 2, 3)
        h = np.zeros((tracks.count, 3, 3))
        g = np.zeros((tracks.count, 3))
        np.add.at(h, tracks.track, np.einsum("oki,okj->oij", jac, jac))
        np.add.at(g, tracks.track, np.einsum("oki,ok->oi", jac, r))
        damp = 1e-9 * np.trace(h, axis1=1, axis2=2)[:, None, None] * np.eye(3)
        ok = np.isfinite(h).all(axis=(1, 2)) & np.isfinite(g).all(axis=1)
        step = np.zeros_like(x)
        solvable = ok & (np.abs(np.linalg.det(h + damp)) > 0)
        step[solvable] = -np.linalg.solve(h[solvable] + damp[solvable], g[solvable, :, None])[
            ..., 0
        ]
        trial = x + step
        trial_cost = cost(trial)
        better = np.isfinite(trial_cost) & (trial_cost < current)
        x[better], current[better] = trial[better], trial_cost[better]
    return x


def triangulation_angles(
    points: np.ndarray, tracks: Tracks, cams: Sequence[PinholeArrays]
) -> np.ndarray:
    """(T,) the widest angle (degrees) between two viewing rays of each track's point."""
    centres = np.stack([c.centre for c in cams])[tracks.view]
    rays = points[tracks.track] - centres
    rays /= np.maximum(np.linalg.norm(rays, axis=1, keepdims=True), 1e-300)
    lengths = tracks.lengths()
    starts = np.concatenate([[0], np.cumsum(lengths)])
    widest = np.zeros(tracks.count)
    for length in np.unique(lengths):
        ids = np.nonzero(lengths == length)[0]
        obs = starts[ids][:, None] + np.arange(length)[None]
        d = rays[obs]  # (T_L, L, 3)
        cos = np.einsum("tai,tbi->tab", d, d).reshape(len(ids), -1).min(axis=1)
        widest[ids] = np.degrees(np.arccos(np.clip(cos, -1.0, 1.0)))
    return widest


def _colours(
    points_xy: np.ndarray, views: np.ndarray, track: np.ndarray, n: int, photos: list[np.ndarray]
) -> np.ndarray:
    """(n, 3) mean bilinear colour of each track over its observations."""
    total = np.zeros((n, 3))
    for v, photo in enumerate(photos):
        sel = views == v
        if not sel.any():
            continue
        h, w = photo.shape[:2]
        x = np.clip(points_xy[sel, 0] - 0.5, 0, w - 1)
        y = np.clip(points_xy[sel, 1] - 0.5, 0, h - 1)
        x0, y0 = np.floor(x).astype(int), np.floor(y).astype(int)
        x1, y1 = np.minimum(x0 + 1, w - 1), np.minimum(y0 + 1, h - 1)
        fx, fy = (x - x0)[:, None], (y - y0)[:, None]
        c = (
            photo[y0, x0] * (1 - fx) * (1 - fy)
            + photo[y0, x1] * fx * (1 - fy)
            + photo[y1, x0] * (1 - fx) * fy
            + photo[y1, x1] * fx * fy
        )
        np.add.at(total, track[sel], c)
    return total / np.maximum(np.bincount(track, minlength=n), 1)[:, None]


def matched_start(
    matches: MatchSet,
    cameras: Sequence[Camera | PinholeArrays],
    photos: Sequence[np.ndarray | Tensor],
    settings: TriangulationSettings | None = None,
) -> MatchedPoints:
    """Triangulate ``matches`` with the given ``cameras`` (one per photo, same order) and
    colour the points from ``photos`` ((H, W, 3) RGB, uint8 or float in [0, 1])."""
    settings = settings or TriangulationSettings()
    if not (len(cameras) == len(photos) == len(matches.keypoints)):
        raise MatchError(
            f"{len(matches.keypoints)} matched photos, {len(cameras)} cameras, {len(photos)} photos"
        )
    cams = _cameras(cameras)
    rgb = [as_float_rgb(p, i) for i, p in enumerate(photos)]
    for i, size in enumerate(matches.sizes):
        if rgb[i].shape[1::-1] != tuple(size):
            raise MatchError(f"photo {i + 1} is {rgb[i].shape[1::-1]}, it was matched at {size}")
    tracks = build_tracks(matches)
    counts = {"tracks": tracks.count, "conflicts": tracks.conflicts}
    x, finite = dlt(tracks, cams)
    if settings.refine_iterations and tracks.count:
        x[finite] = refine(x, tracks, cams, settings.refine_iterations)[finite]
    x[~finite] = 0.0
    err, z = reprojection(x, tracks, cams)
    worst = np.zeros(tracks.count)
    np.maximum.at(worst, tracks.track, np.where(np.isfinite(err), err, np.inf))
    closest = np.full(tracks.count, np.inf)
    np.minimum.at(closest, tracks.track, z)
    angles = triangulation_angles(x, tracks, cams)
    front = finite & (closest > 0)
    small = front & (worst <= settings.max_error_px)
    wide = small & (angles >= settings.min_angle_deg)
    counts.update(
        behind=int((~front).sum()),
        error=int((front & ~small).sum()),
        angle=int((small & ~wide).sum()),
        kept=int(wide.sum()),
    )
    keep_obs = wide[tracks.track]
    renumber = np.cumsum(wide) - 1
    colours = _colours(
        tracks.xy[keep_obs],
        tracks.view[keep_obs],
        renumber[tracks.track[keep_obs]],
        int(wide.sum()),
        rgb,
    )
    points = x[wide]
    if len(points):
        log_scales = knn_log_scales(torch.from_numpy(points), k=settings.neighbours)
        scales = torch.exp(log_scales[:, 0]).numpy()
    else:
        scales = np.zeros(0)
    return MatchedPoints(
        points=points.astype(np.float32),
        colours=np.clip(colours, 0, 1).astype(np.float32),
        scales=scales.astype(np.float32),
        errors=worst[wide].astype(np.float32),
        angles=angles[wide].astype(np.float32),
        views=tracks.lengths()[wide].astype(np.int32),
        observations=Observations(
            point=renumber[tracks.track[keep_obs]].astype(np.int64),
            view=tracks.view[keep_obs].astype(np.int64),
            xy=tracks.xy[keep_obs].astype(np.float32),
        ),
        counts=counts,
    )
