"""Two-view and N-view geometry of pinhole cameras in float64 numpy (engine conventions:
world-to-camera in OpenCV axes, pixel centres at +0.5)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from sparsesplat.engine.camera import Camera


@dataclass(frozen=True)
class PinholeArrays:
    """A camera as float64 arrays."""

    K: np.ndarray
    """(3, 3) intrinsic matrix."""
    world_to_camera: np.ndarray
    """(4, 4) rigid world-to-camera, OpenCV axes."""

    @property
    def centre(self) -> np.ndarray:
        """(3,) camera centre in world coordinates."""
        r, t = self.world_to_camera[:3, :3], self.world_to_camera[:3, 3]
        return -r.T @ t

    @classmethod
    def of(cls, camera: Camera) -> PinholeArrays:
        """The arrays of an engine :class:`Camera`."""
        k = np.array([[camera.fx, 0, camera.cx], [0, camera.fy, camera.cy], [0, 0, 1.0]])
        return cls(k, camera.world_to_camera.detach().cpu().double().numpy().copy())


def skew(v: np.ndarray) -> np.ndarray:
    """The cross-product matrix [v]x of a 3-vector."""
    return np.array([[0, -v[2], v[1]], [v[2], 0, -v[0]], [-v[1], v[0], 0]], dtype=np.float64)


def fundamental(a: PinholeArrays, b: PinholeArrays) -> np.ndarray:
    """F with x_b^T F x_a = 0 for homogeneous pixels x_a in ``a`` and x_b in ``b`` of one world
    point: F = K_b^-T [t]x R K_a^-1 for the relative pose (R, t) taking a's camera frame to b's."""
    ra, ta = a.world_to_camera[:3, :3], a.world_to_camera[:3, 3]
    rb, tb = b.world_to_camera[:3, :3], b.world_to_camera[:3, 3]
    r = rb @ ra.T
    t = tb - r @ ta
    return np.linalg.inv(b.K).T @ skew(t) @ r @ np.linalg.inv(a.K)


def epipolar_distances(
    f: np.ndarray, xa: np.ndarray, xb: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """Per match, the pixel distance of x_b to the epipolar line F x_a in b, and of x_a to the
    line F^T x_b in a ((N, 2) pixel coordinates each)."""
    ha = np.concatenate([xa.astype(np.float64), np.ones((len(xa), 1))], axis=1)
    hb = np.concatenate([xb.astype(np.float64), np.ones((len(xb), 1))], axis=1)
    lb = ha @ f.T  # lines in b
    la = hb @ f  # lines in a
    num = np.abs((hb * lb).sum(axis=1))
    db = num / np.maximum(np.hypot(lb[:, 0], lb[:, 1]), 1e-300)
    da = num / np.maximum(np.hypot(la[:, 0], la[:, 1]), 1e-300)
    return da, db


def project(points: np.ndarray, cam: PinholeArrays) -> tuple[np.ndarray, np.ndarray]:
    """World points (N, 3) -> pixel coordinates (N, 2) and view-space depth z (N,)."""
    q = points @ cam.world_to_camera[:3, :3].T + cam.world_to_camera[:3, 3]
    z = q[:, 2]
    safe = np.where(np.abs(z) > 1e-300, z, 1e-300)
    uv = (q[:, :2] / safe[:, None]) @ cam.K[:2, :2].T + cam.K[:2, 2]
    return uv, z
