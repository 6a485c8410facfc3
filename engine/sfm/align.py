"""Similarity alignment of estimated cameras to reference cameras (for measuring, and for
mapping held-out reference cameras into an estimated frame)."""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from sparsesplat.engine.match.geometry import PinholeArrays, project


@dataclass
class Similarity:
    """x_est = scale * rotation @ x_ref + translation."""

    rotation: np.ndarray
    """(3, 3) rotation taking reference world axes to estimated world axes."""
    scale: float
    """Reference units -> estimated units."""
    translation: np.ndarray
    """(3,) offset in estimated units."""

    def map_world_to_camera(self, w2c_ref: np.ndarray) -> np.ndarray:
        """A reference world-to-camera (4x4, OpenCV) expressed in the estimated frame."""
        r, t = w2c_ref[:3, :3], w2c_ref[:3, 3]
        centre = -r.T @ t
        r_est = r @ self.rotation.T
        c_est = self.scale * self.rotation @ centre + self.translation
        out = np.eye(4)
        out[:3, :3] = r_est
        out[:3, 3] = -r_est @ c_est
        return out

    def map_points(self, points: np.ndarray) -> np.ndarray:
        """(N, 3) reference-frame points expressed in the estimated frame."""
        return self.scale * points @ self.rotation.T + self.translation

    def inverse(self) -> Similarity:
        """The similarity taking the estimated frame back to the reference one."""
        rotation = self.rotation.T
        return Similarity(rotation, 1.0 / self.scale, -rotation @ self.translation / self.scale)


def _project_rotation(m: np.ndarray) -> np.ndarray:
    u, _, vt = np.linalg.svd(m)
    d = np.sign(np.linalg.det(u @ vt))
    return u @ np.diag([1.0, 1.0, d]) @ vt


def rotation_angle_deg(r: np.ndarray) -> float:
    """Angle of the rotation matrix ``r`` in degrees.

    From both its cosine ((trace - 1) / 2) and its sine (half the norm of the skew part):
    the arccosine alone loses small angles to rounding (a rounding of 1e-16 in the cosine
    reads as about 1e-6 degrees, 1e-8 as 0.008)."""
    cos = (float(np.trace(r)) - 1.0) / 2.0
    skew = np.array([r[2, 1] - r[1, 2], r[0, 2] - r[2, 0], r[1, 0] - r[0, 1]])
    sin = float(np.linalg.norm(skew)) / 2.0
    return math.degrees(math.atan2(sin, cos))


def align(est_w2c: list[np.ndarray], ref_w2c: list[np.ndarray]) -> Similarity:
    """The similarity taking the reference frame to the estimated one: the rotation that best
    agrees with every camera's orientation (chordal mean of R_est^T R_ref), then scale and
    translation by least squares on the camera centres."""
    q = _project_rotation(
        sum(e[:3, :3].T @ r[:3, :3] for e, r in zip(est_w2c, ref_w2c, strict=True))
    )
    c_est = np.array([-e[:3, :3].T @ e[:3, 3] for e in est_w2c])
    c_ref = np.array([-r[:3, :3].T @ r[:3, 3] for r in ref_w2c]) @ q.T
    d_est, d_ref = c_est - c_est.mean(0), c_ref - c_ref.mean(0)
    denom = float((d_ref**2).sum())
    scale = float((d_est * d_ref).sum()) / denom if denom > 0 else 1.0
    translation = c_est.mean(0) - scale * c_ref.mean(0)
    return Similarity(q, scale, translation)


def _rodrigues(w: np.ndarray) -> np.ndarray:
    """The rotation by the vector ``w`` (axis times angle in radians)."""
    theta = float(np.linalg.norm(w))
    k = np.array([[0.0, -w[2], w[1]], [w[2], 0.0, -w[0]], [-w[1], w[0], 0.0]])
    if theta < 1e-12:
        return np.eye(3) + k
    k /= theta
    return np.eye(3) + math.sin(theta) * k + (1.0 - math.cos(theta)) * k @ k


REPROJECTION_HUBER_PX = 2.0
"""Residuals (pixels) beyond which :func:`align_reprojection` weighs a point down (Huber): a
wrongly triangulated point or a badly estimated camera must not pull the fit."""
REPROJECTION_START_MAX_PX = 20.0
"""Observations farther than this (pixels) under the camera fit that starts
:func:`align_reprojection` take no part in it."""


def align_reprojection(
    points: np.ndarray,
    est_w2c: list[np.ndarray],
    ref_w2c: list[np.ndarray],
    est_intrinsics: list[np.ndarray],
    ref_intrinsics: list[np.ndarray] | None = None,
    iterations: int = 30,
) -> Similarity:
    """The similarity taking the reference frame to the estimated one under which the
    reference cameras, mapped into the estimate's frame, see the estimate's ``points`` ((N, 3),
    in the estimated frame) where the estimated cameras see them: robust least squares on the
    pixel distances over every camera (one 3x3 K per camera: ``est_intrinsics`` for the
    estimated cameras, ``ref_intrinsics`` for the reference ones, the same when None), by
    Levenberg-Marquardt from :func:`align`'s similarity.

    This is the alignment that held-out cameras near the training ones need: what a held-out
    photo is compared with is the scene seen through it. :func:`align` fits the cameras'
    orientations and centres instead. With three photos of one object, a small turn of a
    camera and a sideways shift of it give nearly the same photo, and the camera fit then put
    DTU's object 2-3 px off in every view; with three forward-facing photos the estimate's
    depths are stretched against the dataset's, so a fit of the 3D points to each other put
    LLFF's views 10 px off. This one keeps both within about a pixel
    (docs/experiments/2026-11-29-scene-alignment.md)."""
    points = np.asarray(points, dtype=np.float64)
    start = align(est_w2c, ref_w2c)
    ref_k = est_intrinsics if ref_intrinsics is None else ref_intrinsics
    # The observations the fit uses, chosen once at the start: in front of the estimated
    # camera and of the mapped reference one, and within REPROJECTION_START_MAX_PX there. A
    # point near a camera's plane projects thousands of pixels away; even a robust loss that
    # grows linearly lets a few of those outweigh every other point (juicebox_table: the
    # median pixel distance went from 2.8 to 36 px while the summed loss fell).
    targets = []
    for w2c, ref, k_est, k_ref in zip(est_w2c, ref_w2c, est_intrinsics, ref_k, strict=True):
        uv, z = project(points, PinholeArrays(k_est, w2c))
        seen, z_ref = project(points, PinholeArrays(k_ref, start.map_world_to_camera(ref)))
        near = np.linalg.norm(seen - uv, axis=1) <= REPROJECTION_START_MAX_PX
        targets.append((uv, (z > 0) & (z_ref > 0) & near))
    if sum(int(used.sum()) for _, used in targets) < 4:
        return start

    def similarity(p: np.ndarray) -> Similarity:
        return Similarity(
            _rodrigues(p[:3]) @ start.rotation,
            start.scale * math.exp(p[3]),
            start.translation + p[4:7] * start.scale,
        )

    def residuals(p: np.ndarray) -> np.ndarray:
        sim = similarity(p)
        out = []
        for ref, k, (uv, used) in zip(ref_w2c, ref_k, targets, strict=True):
            seen, _ = project(points[used], PinholeArrays(k, sim.map_world_to_camera(ref)))
            out.append(seen - uv[used])
        return np.concatenate(out)  # (M, 2)

    def weights(r: np.ndarray) -> np.ndarray:
        norm = np.linalg.norm(r, axis=1)
        return REPROJECTION_HUBER_PX / np.maximum(norm, REPROJECTION_HUBER_PX)

    def cost(r: np.ndarray) -> float:
        norm = np.linalg.norm(r, axis=1)
        h = REPROJECTION_HUBER_PX
        return float(np.where(norm <= h, 0.5 * norm**2, h * (norm - 0.5 * h)).sum())

    p = np.zeros(7)
    r = residuals(p)
    damping = 1e-3
    for _ in range(iterations):
        w = np.repeat(weights(r), 2)
        step = 1e-6
        jac = np.stack(
            [(residuals(p + step * e) - residuals(p - step * e)).ravel() / (2 * step)
             for e in np.eye(7)],
            axis=1,
        )  # fmt: skip
        jtw = jac.T * w
        normal, grad = jtw @ jac, jtw @ r.ravel()
        improved = False
        while damping < 1e12:
            delta = np.linalg.solve(normal + damping * np.diag(np.diag(normal) + 1e-12), -grad)
            trial = residuals(p + delta)
            if cost(trial) < cost(r):
                p, r, damping, improved = p + delta, trial, damping * 0.3, True
                break
            damping *= 10.0
        if not improved or float(np.abs(delta).max()) < 1e-12:
            break
    start_median = float(np.median(np.linalg.norm(residuals(np.zeros(7)), axis=1)))
    if float(np.median(np.linalg.norm(r, axis=1))) > start_median:
        return start  # the robust loss fell by moving the typical point away: keep the start
    return similarity(p)


def rotation_errors_deg(
    est_w2c: list[np.ndarray], ref_w2c: list[np.ndarray], similarity: Similarity
) -> list[float]:
    """Per camera: the angle between its estimated orientation and the aligned reference."""
    return [
        rotation_angle_deg(e[:3, :3].T @ r[:3, :3] @ similarity.rotation.T)
        for e, r in zip(est_w2c, ref_w2c, strict=True)
    ]
