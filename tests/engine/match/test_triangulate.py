"""The matched start on exact synthetic geometry: float64 truth, derived bounds, planted faults.

No matcher runs here (the observations are exact projections), so these tests need neither the
``match`` extra nor the shared data.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from sparsesplat.engine.match import MatchError, TriangulationSettings, matched_start
from sparsesplat.engine.match.geometry import PinholeArrays, project
from sparsesplat.engine.match.result import MatchSet
from sparsesplat.engine.match.settings import MatchSettings
from sparsesplat.engine.match.tracks import build_tracks
from sparsesplat.engine.match.triangulate import dlt, refine, reprojection
from tests.engine.match.synthetic import (
    FOCAL,
    HEIGHT,
    WIDTH,
    arc_cameras,
    cube_points,
    exact_matches,
    flat_photos,
)

U32 = 2.0**-24
"""float32 unit roundoff."""


def _bound(points: np.ndarray, cams: list[PinholeArrays]) -> np.ndarray:
    """Per point, the 3D error the float32 storage of the observations and of the result
    allows. A pixel coordinate below max(W, H) is stored within U32 * max(W, H); an angular
    error e of one ray moves the intersection by up to d * e / sin(theta) along the other ray
    (d its distance to the camera, theta the rays' angle); both coordinates of up to all views
    err at once (factor 2 * sqrt(2), and 2 more for the worst pair); the result is rounded to
    float32 (U32 * |X|)."""
    centres = np.stack([c.centre for c in cams])
    rays = points[:, None] - centres[None]
    dist = np.linalg.norm(rays, axis=2)
    unit = rays / dist[..., None]
    cos = np.einsum("pai,pbi->pab", unit, unit).reshape(len(points), -1).min(axis=1)
    sin = np.sin(np.arccos(np.clip(cos, -1, 1)))
    angular = U32 * max(WIDTH, HEIGHT) / FOCAL
    return 4 * math.sqrt(2) * dist.max(axis=1) * angular / sin + U32 * np.linalg.norm(
        points, axis=1
    )


@pytest.mark.parametrize("views", [2, 3, 5])
def test_exact_observations_give_the_points_within_the_derived_bound(seed: int, views: int) -> None:
    rng = np.random.default_rng(seed)
    cams = arc_cameras(views, 15.0)
    truth = cube_points(rng, 300)
    start = matched_start(
        exact_matches(truth, cams, rng), cams, flat_photos(views, (0.2, 0.4, 0.6))
    )
    assert start.counts["kept"] == len(truth) and start.counts["conflicts"] == 0
    # The kept points come in track order; match them to the truth by nearest neighbour.
    d = np.linalg.norm(start.points[:, None].astype(np.float64) - truth[None], axis=2)
    nearest = d.argmin(axis=1)
    assert len(set(nearest.tolist())) == len(truth)
    err = np.linalg.norm(start.points.astype(np.float64) - truth[nearest], axis=1)
    assert (err <= _bound(truth[nearest], cams)).all(), float((err / _bound(truth, cams)).max())
    assert (start.views == views).all()
    assert float(start.errors.max()) < 1e-3  # pixels: float32 storage of 640-px coordinates
    np.testing.assert_allclose(start.colours, np.broadcast_to([0.2, 0.4, 0.6], (300, 3)), atol=1e-6)


def test_observations_name_each_kept_point_where_each_photo_saw_it(seed: int) -> None:
    """Every kept point is listed once per photo that sees it, at its projection there (the
    observations are exact, so within the float32 storage of the coordinates)."""
    rng = np.random.default_rng(seed)
    cams = arc_cameras(3, 12.0)
    truth = cube_points(rng, 150)
    start = matched_start(exact_matches(truth, cams, rng), cams, flat_photos(3, (1, 1, 1)))
    obs = start.observations
    assert len(obs.point) == int(start.views.sum())
    np.testing.assert_array_equal(np.bincount(obs.point, minlength=len(start.points)), start.views)
    for v, cam in enumerate(cams):
        idx, xy = obs.in_view(v)
        uv, z = project(start.points[idx].astype(np.float64), cam)
        assert (z > 0).all()
        assert float(np.abs(uv - xy).max()) < 1e-3  # pixels, as the reprojection error above


def test_scales_are_the_rms_distance_to_the_three_nearest_points(seed: int) -> None:
    rng = np.random.default_rng(seed)
    cams = arc_cameras(2, 20.0)
    truth = cube_points(rng, 200)
    start = matched_start(exact_matches(truth, cams, rng), cams, flat_photos(2, (1, 1, 1)))
    pts = start.points.astype(np.float64)
    d2 = ((pts[:, None] - pts[None]) ** 2).sum(axis=2)
    np.fill_diagonal(d2, np.inf)
    ref = np.sqrt(np.sort(d2, axis=1)[:, :3].mean(axis=1))
    # float32 points and the trainer's float64 k-NN: relative error of a few roundoffs.
    np.testing.assert_allclose(start.scales, ref, rtol=1e-5)


@pytest.mark.parametrize("degrees", [1.0, 3.0])
def test_a_planted_wrong_camera_raises_the_error_and_its_points_are_filtered(
    seed: int, degrees: float
) -> None:
    rng = np.random.default_rng(seed)
    cams = arc_cameras(3, 15.0)
    truth = cube_points(rng, 200)
    matches = exact_matches(truth, cams, rng)
    turn = math.radians(degrees)
    # Tilted about its own x axis: its projections move up or down, across the (horizontal)
    # epipolar lines of the arc. A turn about the vertical would move them along those lines,
    # which the other views cannot tell from a change of depth.
    spin = np.array(
        [[1, 0, 0], [0, math.cos(turn), -math.sin(turn)], [0, math.sin(turn), math.cos(turn)]]
    )
    bad = spin @ cams[2].world_to_camera[:3]  # turned about its own centre
    wrong = [cams[0], cams[1], PinholeArrays(cams[2].K, np.vstack([bad, [0, 0, 0, 1]]))]
    photos = flat_photos(3, (0.5, 0.5, 0.5))
    loose = matched_start(matches, wrong, photos, TriangulationSettings(max_error_px=1e9))
    # A camera turned by `degrees` moves its projections by about f * tan(degrees); the least
    # squares point spreads that over the three views, so each point misses by a good part of
    # it: far above the sub-millipixel error of the right cameras.
    shift = FOCAL * math.tan(turn)
    assert float(np.median(loose.errors)) > 0.2 * shift
    # The worst view keeps about 2/3 of the shift (1 degree: 8.7 px -> ~5.8 px); at 0.5 degree
    # (~2.9 px) the slightly tilted epipolar lines let a few points slip under 2 px.
    strict = matched_start(matches, wrong, photos, TriangulationSettings(max_error_px=2.0))
    assert strict.counts["kept"] == 0 and strict.counts["error"] == len(truth)
    right = matched_start(matches, cams, photos, TriangulationSettings(max_error_px=2.0))
    assert right.counts["kept"] == len(truth)


def test_rays_at_a_small_angle_are_filtered(seed: int) -> None:
    rng = np.random.default_rng(seed)
    cams = arc_cameras(2, 0.3)
    truth = cube_points(rng, 100, half=0.5)
    matches = exact_matches(truth, cams, rng)
    photos = flat_photos(2, (0, 0, 0))
    narrow = matched_start(matches, cams, photos, TriangulationSettings(min_angle_deg=1.0))
    assert narrow.counts["kept"] == 0 and narrow.counts["angle"] == len(truth)
    kept = matched_start(matches, cams, photos, TriangulationSettings(min_angle_deg=0.1))
    assert kept.counts["kept"] == len(truth)
    assert float(kept.angles.min()) >= 0.1 and float(kept.angles.max()) < 1.0


def test_points_behind_the_cameras_are_dropped(seed: int) -> None:
    rng = np.random.default_rng(seed)
    cams = arc_cameras(2, 20.0)
    # Points behind both cameras project to valid-looking pixels (the sign of z cancels).
    behind = cube_points(rng, 50, half=0.3) + np.array([0.0, 0.3, -8.0])
    assert all((project(behind, c)[1] < 0).all() for c in cams)
    start = matched_start(exact_matches(behind, cams, rng), cams, flat_photos(2, (0, 0, 0)))
    assert start.counts["kept"] == 0 and start.counts["behind"] == 50


def test_gauss_newton_lowers_the_reprojection_error_of_noisy_observations(seed: int) -> None:
    rng = np.random.default_rng(seed)
    cams = arc_cameras(4, 10.0)
    truth = cube_points(rng, 200)
    tracks = build_tracks(exact_matches(truth, cams, rng, noise_px=0.7))
    x0, finite = dlt(tracks, cams)
    x1 = refine(x0, tracks, cams, 5)

    def per_track(x: np.ndarray) -> np.ndarray:
        err, _ = reprojection(x, tracks, cams)
        return np.bincount(tracks.track, err * err, minlength=tracks.count)

    # Each point's summed squared error (what the steps minimise) never rises, and in all
    # falls: the DLT minimises an algebraic error, not the pixel one.
    assert finite.all()
    before, after = per_track(x0), per_track(x1)
    assert (after <= before).all()
    assert after.sum() < before.sum()


def test_a_component_holding_two_keypoints_of_one_photo_is_dropped(seed: int) -> None:
    rng = np.random.default_rng(seed)
    cams = arc_cameras(3, 15.0)
    truth = cube_points(rng, 20)
    m = exact_matches(truth, cams, rng)
    # Rewire one (0, 2) match to another point's keypoint in photo 2: the two tracks join
    # through photos 0-1-2 and hold two keypoints of photo 2.
    rows = m.matches[(0, 2)].copy()
    rows[0, 1] = rows[1, 1]
    broken = MatchSet(m.keypoints, {**m.matches, (0, 2): rows}, m.scores, m.sizes, m.settings)
    tracks = build_tracks(broken)
    assert tracks.conflicts == 1 and tracks.count == len(truth) - 2
    assert (tracks.lengths() == 3).all()


def test_inputs_that_disagree_are_refused() -> None:
    cams = arc_cameras(2, 10.0)
    m = exact_matches(cube_points(np.random.default_rng(0), 10), cams, np.random.default_rng(1))
    with pytest.raises(MatchError, match="2 matched photos, 1 cameras"):
        matched_start(m, cams[:1], flat_photos(2, (0, 0, 0)))
    with pytest.raises(MatchError, match="matched at"):
        matched_start(m, cams, [np.zeros((10, 10, 3), np.float32)] * 2)
    with pytest.raises(MatchError, match="max_error_px"):
        TriangulationSettings(max_error_px=0)
    with pytest.raises(MatchError, match="unknown matcher"):
        MatchSettings(method="superglue")
