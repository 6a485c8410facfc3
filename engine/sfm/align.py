"""Similarity alignment of estimated cameras to reference cameras (for measuring, and for
mapping held-out reference cameras into an estimated frame)."""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np


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


def _umeyama(ref: np.ndarray, est: np.ndarray) -> Similarity:
    """Least-squares similarity with est ~ scale * rotation @ ref + translation (Umeyama)."""
    mu_ref, mu_est = ref.mean(0), est.mean(0)
    a, b = ref - mu_ref, est - mu_est
    u, s, vt = np.linalg.svd(b.T @ a / len(ref))
    d = np.array([1.0, 1.0, np.sign(np.linalg.det(u @ vt)) or 1.0])
    rotation = u @ np.diag(d) @ vt
    spread = float((a**2).sum(axis=1).mean())
    scale = float((s * d).sum()) / spread if spread > 0 else 1.0
    return Similarity(rotation, scale, mu_est - scale * rotation @ mu_ref)


MIN_ALIGN_POINTS = 4
"""Fewest corresponding points :func:`align_points` accepts (three fix a similarity; one more
lets a wrong point show)."""


def align_points(ref: np.ndarray, est: np.ndarray, trim: float = 3.0) -> Similarity:
    """The similarity taking the reference frame to the estimated one from corresponding
    scene points ((N, 3) each, the same points in both frames): least squares, then once more
    over the points whose residual is within ``trim`` times the median residual, so that a
    few wrongly triangulated points do not tilt it.

    Where :func:`align` matches the cameras, this matches the scene. With a few cameras that
    all look at one object the two differ: a small turn of a camera and a sideways shift of it
    give nearly the same photo of a distant object, so the estimate can be off the reference by
    such a pair in every camera and still place the object to a fraction of a pixel; the camera
    alignment then puts the object pixels off (DTU: 2-3 px at 400x300) where this one keeps it
    in place (docs/experiments/2026-11-29-scene-alignment.md)."""
    ref = np.asarray(ref, dtype=np.float64)
    est = np.asarray(est, dtype=np.float64)
    if ref.shape != est.shape or ref.ndim != 2 or ref.shape[1] != 3:
        raise ValueError(f"points must be two (N, 3) arrays, got {ref.shape} and {est.shape}")
    finite = np.isfinite(ref).all(axis=1) & np.isfinite(est).all(axis=1)
    ref, est = ref[finite], est[finite]
    if len(ref) < MIN_ALIGN_POINTS:
        raise ValueError(f"a similarity needs at least {MIN_ALIGN_POINTS} points, got {len(ref)}")
    sim = _umeyama(ref, est)
    residual = np.linalg.norm(sim.map_points(ref) - est, axis=1)
    keep = residual <= trim * float(np.median(residual))
    if MIN_ALIGN_POINTS <= keep.sum() < len(ref):
        sim = _umeyama(ref[keep], est[keep])
    return sim


def rotation_errors_deg(
    est_w2c: list[np.ndarray], ref_w2c: list[np.ndarray], similarity: Similarity
) -> list[float]:
    """Per camera: the angle between its estimated orientation and the aligned reference."""
    return [
        rotation_angle_deg(e[:3, :3].T @ r[:3, :3] @ similarity.rotation.T)
        for e, r in zip(est_w2c, ref_w2c, strict=True)
    ]
