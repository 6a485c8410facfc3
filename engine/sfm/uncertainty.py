"""How well the photos pin down each camera: the spread of its orientation under the matches'
noise, from the bundle adjustment's own curvature at the solution.

A reconstruction can fit its matches to a pixel and still be wrong when the matches do not
determine the cameras: a small object seen in a narrow patch of each photo (the Blender mic at
400 px) lets a turn of one camera trade against the depth of the points, so many orientations
fit equally well and the mapper returns one of them. Its reprojection error does not show
this; the covariance of the solution does.

The covariance is the Gauss-Newton one of the reprojection residuals, with the shared pinhole
intrinsics held fixed (their uncertainty would only widen it), points eliminated by the Schur
complement, and the noise scaled by the residuals' own variance. The world's similarity (7
degrees of freedom) is not fixed: what is reported, the orientation of one camera *relative to
another*, does not depend on it, so the pseudo-inverse of the reduced camera matrix serves.

Measured (docs/experiments/2026-11-29-camera-uncertainty.md): the correct 3-view solutions of
the shared scenes give at most 0.79° (juicebox_table), four neighbouring views of mic at 400 px
1.1-1.4°, the wrong frames of mic's 8 views and of beer_can 2.4-2.7°.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class BundleProblem:
    """A solved reconstruction as plain arrays (float64): what the covariance is computed from."""

    world_to_camera: np.ndarray
    """(C, 4, 4) world-to-camera of the placed photos, OpenCV axes."""
    intrinsics: tuple[float, float, float, float]
    """The shared camera's (fx, fy, cx, cy), pixels."""
    points: np.ndarray
    """(P, 3) triangulated points."""
    camera_index: np.ndarray
    """(M,) int: which camera (row of ``world_to_camera``) made each observation."""
    point_index: np.ndarray
    """(M,) int: which point each observation is of."""
    pixels: np.ndarray
    """(M, 2) observed pixel positions (the pixel grid's convention of ``intrinsics``)."""


def residuals(problem: BundleProblem) -> np.ndarray:
    """(M, 2) projected minus observed pixel positions."""
    camera = _camera_points(problem)
    fx, fy, cx, cy = problem.intrinsics
    projected = np.stack(
        [fx * camera[:, 0] / camera[:, 2] + cx, fy * camera[:, 1] / camera[:, 2] + cy], axis=1
    )
    return projected - problem.pixels


def relative_rotation_std_deg(problem: BundleProblem) -> np.ndarray:
    """(C, C) the 1-sigma spread, in degrees, of each camera's orientation relative to each
    other camera (the largest over the three rotation axes; 0 on the diagonal). ``inf`` for a
    camera whose orientation the observations do not constrain at all."""
    n = len(problem.world_to_camera)
    jc, jx = _jacobians(problem)
    m = len(problem.pixels)
    p = len(problem.points)
    # Reduced camera system S = U - sum_j W_j V_j^-1 W_j^T, U block-diagonal per camera.
    u = np.zeros((n, 6, 6))
    np.add.at(u, problem.camera_index, np.einsum("mri,mrj->mij", jc, jc))
    v = np.zeros((p, 3, 3))
    np.add.at(v, problem.point_index, np.einsum("mri,mrj->mij", jx, jx))
    w = np.einsum("mri,mrj->mij", jc, jx)  # (M, 6, 3): observation m's camera-point block
    s = np.zeros((6 * n, 6 * n))
    for c in range(n):
        s[6 * c : 6 * c + 6, 6 * c : 6 * c + 6] = u[c]
    # A point seen under a tiny angle has a nearly singular V_j: damp it by 1e-12 of its own
    # scale, so that it inverts (it then carries almost no information, as it should).
    scale = np.trace(v, axis1=1, axis2=2)[:, None, None]
    v_inv = np.linalg.inv(v + 1e-12 * scale * np.eye(3) + 1e-300)
    order = np.argsort(problem.point_index, kind="stable")
    bounds = np.searchsorted(problem.point_index[order], np.arange(p + 1))
    for j in range(p):
        obs = order[bounds[j] : bounds[j + 1]]
        left = w[obs] @ v_inv[j]  # (k, 6, 3)
        for a, oa in enumerate(obs):
            ca = 6 * problem.camera_index[oa]
            for ob in obs:
                cb = 6 * problem.camera_index[ob]
                s[ca : ca + 6, cb : cb + 6] -= left[a] @ w[ob].T
    if not np.isfinite(s).all():  # a point on a camera's plane: nothing can be said
        return np.where(np.eye(n, dtype=bool), 0.0, np.inf)
    free = 6 * n + 3 * p - 7
    sigma2 = float(np.sum(residuals(problem) ** 2)) / max(2 * m - free, 1)
    covariance = np.linalg.pinv(s, rcond=1e-10, hermitian=True) * sigma2
    out = np.zeros((n, n))
    for a in range(n):
        for b in range(a + 1, n):
            ra, rb = slice(6 * a, 6 * a + 3), slice(6 * b, 6 * b + 3)
            block = (
                covariance[ra, ra] + covariance[rb, rb] - covariance[ra, rb] - covariance[rb, ra]
            )
            largest = float(np.linalg.eigvalsh(0.5 * (block + block.T)).max())
            out[a, b] = out[b, a] = math.degrees(math.sqrt(max(largest, 0.0)))
    return out


def _camera_points(problem: BundleProblem) -> np.ndarray:
    w2c = problem.world_to_camera[problem.camera_index]
    return (
        np.einsum("mij,mj->mi", w2c[:, :3, :3], problem.points[problem.point_index]) + w2c[:, :3, 3]
    )


def _jacobians(problem: BundleProblem) -> tuple[np.ndarray, np.ndarray]:
    """Per observation the (2, 6) derivative by its camera's (rotation, translation) and the
    (2, 3) derivative by its point. The rotation is perturbed on the world side,
    R <- R exp([w]x), so a common turn of all cameras (a gauge motion) is the same w for each
    and drops out of relative orientations."""
    fx, fy, _, _ = problem.intrinsics
    q = _camera_points(problem)
    z = q[:, 2]
    jp = np.zeros((len(q), 2, 3))
    jp[:, 0, 0] = fx / z
    jp[:, 0, 2] = -fx * q[:, 0] / z**2
    jp[:, 1, 1] = fy / z
    jp[:, 1, 2] = -fy * q[:, 1] / z**2
    rotation = problem.world_to_camera[problem.camera_index][:, :3, :3]
    x = problem.points[problem.point_index]
    skew = np.zeros((len(q), 3, 3))
    skew[:, 0, 1], skew[:, 0, 2] = -x[:, 2], x[:, 1]
    skew[:, 1, 0], skew[:, 1, 2] = x[:, 2], -x[:, 0]
    skew[:, 2, 0], skew[:, 2, 1] = -x[:, 1], x[:, 0]
    d_rotation = jp @ (-rotation @ skew)  # d(R X) / dw = -R [X]x
    jc = np.concatenate([d_rotation, jp], axis=2)
    jx = jp @ rotation
    return jc, jx
