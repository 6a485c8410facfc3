"""The orientation spread of a solved reconstruction (engine/sfm/uncertainty.py) against a
brute-force float64 reference, its invariance to the world's frame, and the checks built on
it: a photo its matches do not pin down is refused by name; photos outside the matcher's
reach are left out only when the rest may stand."""

from __future__ import annotations

import math

import numpy as np
import pytest

from sparsesplat.engine.sfm.align import _rodrigues
from sparsesplat.engine.sfm.check import (
    MAX_ROTATION_STD_DEG,
    left_out,
    result_problem,
    rotation_std_by_photo,
)
from sparsesplat.engine.sfm.reconstruct import MatchStats, Observed, PairStats, Reconstruction
from sparsesplat.engine.sfm.uncertainty import (
    BundleProblem,
    relative_rotation_std_deg,
    residuals,
)
from tests.engine.sfm.textured import look_at

INTRINSICS = (600.0, 600.0, 320.0, 240.0)


def _problem(
    seed: int, radius: float, distance: float, noise_px: float, cameras: int = 3, count: int = 150
) -> BundleProblem:
    """``cameras`` cameras on an arc 30 degrees wide looking at a ball of points of
    ``radius`` around the origin from ``distance``, every point seen by every camera, the
    observations the exact projections plus Gaussian noise."""
    rng = np.random.default_rng(seed)
    points = rng.normal(size=(count, 3))
    points *= radius / np.abs(points).max()
    angles = np.radians(np.linspace(-15, 15, cameras))
    w2c = np.stack(
        [
            look_at(distance * np.array([math.sin(a), 0.0, -math.cos(a)]), np.zeros(3))
            for a in angles
        ]
    )
    cam = np.repeat(np.arange(cameras), len(points))
    pt = np.tile(np.arange(len(points)), cameras)
    exact = BundleProblem(w2c, INTRINSICS, points, cam, pt, np.zeros((len(cam), 2)))
    pixels = residuals(exact) + rng.normal(scale=noise_px, size=(len(cam), 2))
    return BundleProblem(w2c, INTRINSICS, points, cam, pt, pixels)


def _reference(problem: BundleProblem) -> np.ndarray:
    """The same spread from the full normal matrix of a central-difference Jacobian of the
    residuals over every parameter (6 per camera, 3 per point), float64."""
    n, p = len(problem.world_to_camera), len(problem.points)

    def residual(params: np.ndarray) -> np.ndarray:
        w2c = problem.world_to_camera.copy()
        for c in range(n):
            w, t = params[6 * c : 6 * c + 3], params[6 * c + 3 : 6 * c + 6]
            w2c[c, :3, :3] = problem.world_to_camera[c, :3, :3] @ _rodrigues(w)
            w2c[c, :3, 3] = problem.world_to_camera[c, :3, 3] + t
        points = problem.points + params[6 * n :].reshape(p, 3)
        moved = BundleProblem(
            w2c, problem.intrinsics, points, problem.camera_index, problem.point_index,
            problem.pixels,
        )  # fmt: skip
        return residuals(moved).ravel()

    size = 6 * n + 3 * p
    h = 1e-6
    jac = np.stack([(residual(h * e) - residual(-h * e)) / (2 * h) for e in np.eye(size)], axis=1)
    r = residual(np.zeros(size))
    sigma2 = float(r @ r) / (len(r) - (size - 7))
    cov = np.linalg.pinv(jac.T @ jac, rcond=1e-10, hermitian=True) * sigma2
    out = np.zeros((n, n))
    for a in range(n):
        for b in range(a + 1, n):
            ia, ib = slice(6 * a, 6 * a + 3), slice(6 * b, 6 * b + 3)
            block = cov[ia, ia] + cov[ib, ib] - cov[ia, ib] - cov[ib, ia]
            out[a, b] = out[b, a] = math.degrees(math.sqrt(np.linalg.eigvalsh(block).max()))
    return out


def test_spread_equals_the_brute_force_reference() -> None:
    problem = _problem(seed=3, radius=1.0, distance=4.0, noise_px=0.7, count=30)
    got = relative_rotation_std_deg(problem)
    want = _reference(problem)
    # Both are the same Gauss-Newton covariance; they differ by the central differences'
    # truncation (~h^2 relative) and by the 1e-12 relative damping of each point's block.
    assert np.all(np.diag(got) == 0)
    np.testing.assert_allclose(got, want, rtol=1e-6)


def test_spread_does_not_depend_on_the_world_frame() -> None:
    problem = _problem(seed=4, radius=1.0, distance=4.0, noise_px=0.5)
    rotation = _rodrigues(np.array([0.3, -1.1, 0.7]))
    scale, shift = 2.5, np.array([1.0, -2.0, 0.5])
    similarity = np.eye(4)  # world -> new world: x' = s R x + shift
    similarity[:3, :3] = scale * rotation
    similarity[:3, 3] = shift
    w2c = problem.world_to_camera @ np.linalg.inv(similarity)
    w2c[:, :3, :] *= scale  # keep a rigid camera: the camera frame scales with the world
    w2c[:, 3, :] = [0, 0, 0, 1]
    moved = BundleProblem(
        w2c, problem.intrinsics, problem.points @ (scale * rotation).T + shift,
        problem.camera_index, problem.point_index, problem.pixels,
    )  # fmt: skip
    np.testing.assert_allclose(np.abs(residuals(moved)), np.abs(residuals(problem)), atol=1e-9)
    np.testing.assert_allclose(
        relative_rotation_std_deg(moved), relative_rotation_std_deg(problem), rtol=1e-6
    )


def test_a_small_far_object_leaves_the_cameras_loose() -> None:
    # The same noise: a ball filling most of the frame against one filling a tenth of it (the
    # mic case), where a turn of a camera trades against the points' depth. The spread scales
    # as the noise over the object's size squared (measured 0.30° against 6.2°).
    near = relative_rotation_std_deg(_problem(seed=5, radius=1.5, distance=4.0, noise_px=0.5))
    far = relative_rotation_std_deg(_problem(seed=5, radius=0.25, distance=4.0, noise_px=1.0))
    assert near.max() < 0.5 * MAX_ROTATION_STD_DEG
    assert far.max() > 2 * MAX_ROTATION_STD_DEG


def test_a_point_on_a_camera_plane_gives_an_infinite_spread_that_sinks_a_partial_set() -> None:
    problem = _problem(seed=8, radius=1.5, distance=4.0, noise_px=0.3)
    points = problem.points.copy()
    centre = -problem.world_to_camera[0, :3, :3].T @ problem.world_to_camera[0, :3, 3]
    points[0] = centre  # depth 0 in camera 0
    planted = BundleProblem(
        problem.world_to_camera, problem.intrinsics, points, problem.camera_index,
        problem.point_index, problem.pixels,
    )  # fmt: skip
    with np.errstate(divide="ignore", invalid="ignore"):
        spread = relative_rotation_std_deg(planted)
        assert np.all(np.diag(spread) == 0) and np.all(np.isinf(spread[~np.eye(3, dtype=bool)]))
        stats = _stats(4, {(0, 1): 40, (1, 2): 40, (0, 2): 40})
        problem_text = result_problem(NAMES, stats, _reconstruction(planted, [0, 1, 2]), 30)
    assert problem_text is not None and "could be off by any angle" in problem_text


def _reconstruction(problem: BundleProblem, photos: list[int]) -> Reconstruction:
    return Reconstruction(
        world_to_camera={i: problem.world_to_camera[k] for k, i in enumerate(photos)},
        intrinsics=problem.intrinsics,
        points=problem.points,
        colours=np.zeros((len(problem.points), 3), np.float32),
        point_views=[photos] * len(problem.points),
        reprojection_error_px=float(np.linalg.norm(residuals(problem), axis=1).mean()),
        observations=Observed(
            photo=np.asarray(photos)[problem.camera_index],
            point=problem.point_index,
            pixels=problem.pixels,
        ),
    )


def _stats(n: int, pairs: dict[tuple[int, int], int]) -> MatchStats:
    stats = MatchStats([500] * n)
    for pair, inliers in pairs.items():
        stats.pairs[pair] = PairStats(inliers, 20.0)
    return stats


NAMES = ["a.png", "b.png", "c.png", "d.png"]


def test_a_loose_photo_sinks_a_partial_set_by_name() -> None:
    stats = _stats(4, {(0, 1): 40, (1, 2): 40, (0, 2): 40})  # photo 4 shares nothing
    firm = _reconstruction(_problem(seed=6, radius=1.5, distance=4.0, noise_px=0.3), [0, 1, 2])
    assert result_problem(NAMES, stats, firm, 30) is None
    loose = _reconstruction(_problem(seed=6, radius=0.2, distance=4.0, noise_px=1.0), [0, 1, 2])
    spread = rotation_std_by_photo(loose)
    worst = max(spread, key=lambda i: spread[i])
    assert spread[worst] > MAX_ROTATION_STD_DEG
    problem = result_problem(NAMES, stats, loose, 30)
    assert problem is not None and "do not pin it down" in problem
    assert f"photo {worst + 1} ({NAMES[worst]})" in problem
    # A complete set is not held to the spread: all its photos were placed by their matches.
    assert (
        result_problem(NAMES[:3], _stats(3, {(0, 1): 40, (1, 2): 40, (0, 2): 40}), loose, 30)
        is None
    )


@pytest.mark.parametrize(
    ("pairs", "placed", "kept"),
    [
        # d shares nothing with the placed three: left out by name.
        ({(0, 1): 40, (1, 2): 40, (0, 2): 40, (3, 0): 5}, [0, 1, 2], True),
        # d shares 35 verified matches with b yet was not placed with it: the set is refused.
        ({(0, 1): 40, (1, 2): 40, (0, 2): 40, (1, 3): 35}, [0, 1, 2], False),
        # two of four placed: too little of the set.
        ({(0, 1): 40}, [0, 1], False),
    ],
)
def test_unplaced_photos_are_left_out_only_when_outside_reach(
    pairs: dict[tuple[int, int], int], placed: list[int], kept: bool
) -> None:
    rec = _reconstruction(
        _problem(seed=7, radius=1.5, distance=4.0, noise_px=0.3, cameras=len(placed)), placed
    )
    stats = _stats(4, {tuple(sorted(k)): v for k, v in pairs.items()})  # type: ignore[misc]
    reasons = left_out(NAMES, stats, rec, 30)
    problem = result_problem(NAMES, stats, rec, 30)
    if kept:
        assert reasons is not None and list(reasons) == [3]
        assert "photo 4 (d.png) was left out" in reasons[3] and problem is None
    else:
        assert reasons is None
        assert problem is not None and "could not be placed" in problem
