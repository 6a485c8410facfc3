"""The epipolar measure the matcher bench relies on, on exact float64 geometry."""

from __future__ import annotations

import numpy as np

from sparsesplat.engine.match.geometry import epipolar_distances, fundamental, project
from tests.engine.match.synthetic import arc_cameras, cube_points


def test_true_correspondences_lie_on_their_epipolar_lines(seed: int) -> None:
    rng = np.random.default_rng(seed)
    a, b = arc_cameras(2, 25.0)
    pts = cube_points(rng, 200)
    xa, xb = project(pts, a)[0], project(pts, b)[0]
    da, db = epipolar_distances(fundamental(a, b), xa, xb)
    # float64 throughout: pixel coordinates below 640 keep ~1e-13 px; the F product a few
    # orders more.
    assert da.max() < 1e-8 and db.max() < 1e-8


def test_a_shift_across_the_line_is_measured_in_pixels(seed: int) -> None:
    rng = np.random.default_rng(seed)
    a, b = arc_cameras(2, 25.0)
    pts = cube_points(rng, 100)
    xa, xb = project(pts, a)[0], project(pts, b)[0]
    f = fundamental(a, b)
    lines = np.concatenate([xa, np.ones((len(xa), 1))], axis=1) @ f.T
    normal = lines[:, :2] / np.linalg.norm(lines[:, :2], axis=1, keepdims=True)
    shift = rng.uniform(0.1, 5.0, len(xa))
    _, db = epipolar_distances(f, xa, xb + shift[:, None] * normal)
    np.testing.assert_allclose(db, shift, rtol=1e-9, atol=1e-9)
    # Along the line: no distance at all.
    along = np.stack([-normal[:, 1], normal[:, 0]], axis=1)
    _, db = epipolar_distances(f, xa, xb + 7.0 * along)
    assert db.max() < 1e-8


def test_the_fundamental_matrix_has_rank_two_and_swaps_by_transpose() -> None:
    a, b = arc_cameras(2, 25.0)
    f_ab, f_ba = fundamental(a, b), fundamental(b, a)
    s = np.linalg.svd(f_ab, compute_uv=False)
    assert s[2] < 1e-12 * s[0]
    np.testing.assert_allclose(
        f_ba / np.linalg.norm(f_ba), f_ab.T / np.linalg.norm(f_ab), atol=1e-12
    )
