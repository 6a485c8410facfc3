"""The matchers bench's precision figure: each match's distance to the dataset's epipolar
lines, checked on exact two-view geometry."""

from __future__ import annotations

import numpy as np

from benchmarks.matchers import epipolar_errors, median_px
from sparsesplat.engine.match.geometry import fundamental, project
from tests.engine.match.synthetic import arc_cameras, cube_points


def test_exact_matches_lie_on_their_epipolar_lines_and_a_moved_one_by_its_move() -> None:
    """Exact projections are within 1e-9 px of the lines; a match moved by d pixels across
    its line in the second photo (along the line's normal) is at least d away (at most 2d:
    the two views' scales differ by less than that here), and one moved along it is not."""
    rng = np.random.default_rng(3)
    a, b = arc_cameras(2, 25.0)
    points = cube_points(rng, 50)
    xa, _ = project(points, a)
    xb, _ = project(points, b)
    f = fundamental(a, b)
    assert epipolar_errors(f, xa, xb).max() < 1e-9
    line = np.concatenate([xa, np.ones((50, 1))], axis=1) @ f.T  # lines in b
    normal = line[:, :2] / np.linalg.norm(line[:, :2], axis=1, keepdims=True)
    moves = rng.uniform(-3.0, 3.0, 50)
    errors = epipolar_errors(f, xa, xb + moves[:, None] * normal)
    # The distance in b is |d|; the one in a differs by the local scale of the two views, and
    # the figure is the larger of the two.
    assert np.all(errors >= np.abs(moves) - 1e-9) and np.all(errors <= 2.0 * np.abs(moves))
    # Moved along its line instead, a match stays on it.
    along = np.stack([-normal[:, 1], normal[:, 0]], axis=1)
    assert epipolar_errors(f, xa, xb + moves[:, None] * along).max() < 1e-6


def test_the_median_of_no_matches_is_none() -> None:
    assert median_px(np.zeros(0)) is None
    assert median_px(np.array([3.0, 1.0, 2.0])) == 2.0
