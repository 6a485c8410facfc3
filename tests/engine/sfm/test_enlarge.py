"""Small photos enlarged for SIFT (engine/sfm/enlarge.py) and the estimate brought back to the
photos' own pixels: the factor, the enlarged files, the coordinate convention the scaling
relies on, and the scaling of a solved reconstruction against its float64 original."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from PIL import Image

from sparsesplat.engine.sfm.check import rotation_std_by_photo
from sparsesplat.engine.sfm.enlarge import enlarge_factor, write_enlarged
from sparsesplat.engine.sfm.reconstruct import CameraPrior, MatchStats, PairStats
from sparsesplat.engine.sfm.uncertainty import residuals
from tests.engine.sfm.test_uncertainty import _problem, _reconstruction


@pytest.mark.parametrize(
    ("size", "target", "factor"),
    [((400, 400), 800, 2), ((400, 300), 800, 2), ((360, 640), 800, 2), ((300, 200), 800, 3),
     ((800, 600), 800, 1), ((960, 540), 800, 1), ((400, 400), None, 1)],
)  # fmt: skip
def test_factor_is_the_smallest_whole_one_that_reaches_the_target(
    size: tuple[int, int], target: int | None, factor: int
) -> None:
    assert enlarge_factor(*size, target) == factor


def test_enlarged_photos_keep_their_names_alpha_and_pixel_coordinates(tmp_path: Path) -> None:
    """A smooth blob centred at (20.3, 11.7) in the photo's continuous pixel coordinates (the
    pixel centres at +0.5) has its centroid at twice that in the 2x photo: the convention
    under which the estimate's pixel quantities are divided by the factor."""
    h, w = 32, 48
    v, u = np.meshgrid(np.arange(h) + 0.5, np.arange(w) + 0.5, indexing="ij")
    blob = np.exp(-((u - 20.3) ** 2 + (v - 11.7) ** 2) / (2 * 3.0**2))
    grey = np.round(255 * blob).astype(np.uint8)
    Image.fromarray(np.stack([grey] * 3, axis=2)).save(tmp_path / "a.jpg", format="PNG")
    rgba = np.zeros((h, w, 4), np.uint8)
    rgba[..., 3] = 255
    rgba[:8, :8, 3] = 0
    Image.fromarray(rgba, "RGBA").save(tmp_path / "b.png")
    out = write_enlarged(tmp_path, ["a.jpg", "b.png"], tmp_path / "big", 2)
    with Image.open(out / "a.jpg") as a, Image.open(out / "b.png") as b:
        assert a.size == (2 * w, 2 * h) and a.format == "PNG" and a.mode == "RGB"
        assert b.size == (2 * w, 2 * h) and b.mode == "RGBA"
        big = np.asarray(a, dtype=np.float64)[..., 0]
    vv, uu = np.meshgrid(np.arange(2 * h) + 0.5, np.arange(2 * w) + 0.5, indexing="ij")
    centroid = np.array([(uu * big).sum(), (vv * big).sum()]) / big.sum()
    # A wrong convention (pixel corners, or centres at 0) puts it 0.5-1 px off; the 8-bit
    # rounding and the bicubic kernel's overshoot move it by about 0.006 px here.
    assert np.abs(centroid - 2 * np.array([20.3, 11.7])).max() < 0.05


def test_a_reconstruction_scaled_back_has_residuals_scaled_and_the_same_spread() -> None:
    problem = _problem(seed=3, radius=1.0, distance=5.0, noise_px=0.5)
    rec = _reconstruction(problem, [0, 1, 2])
    half = rec.scaled(0.5)
    _, original = rec.bundle_problem()
    _, scaled = half.bundle_problem()
    np.testing.assert_allclose(residuals(scaled), 0.5 * residuals(original), rtol=0, atol=1e-9)
    assert half.reprojection_error_px == pytest.approx(0.5 * rec.reprojection_error_px)
    assert half.intrinsics == pytest.approx(tuple(0.5 * x for x in rec.intrinsics))
    for i, spread in rotation_std_by_photo(rec).items():
        assert rotation_std_by_photo(half)[i] == pytest.approx(spread, rel=1e-9)
    assert rec.observations.pixels is not half.observations.pixels  # the original untouched
    assert np.array_equal(half.points, rec.points) and half.world_to_camera is rec.world_to_camera


def test_prior_and_match_statistics_scale_their_pixels_only() -> None:
    prior = CameraPrior(500.0, 510.0, 200.0, 150.0, fixed=True)
    assert prior.scaled(2) == CameraPrior(1000.0, 1020.0, 400.0, 300.0, fixed=True)
    stats = MatchStats([40, 50], {(0, 1): PairStats(120, 8.0)})
    half = stats.scaled(0.5)
    assert half.keypoints == [40, 50] and half.inliers(0, 1) == 120
    assert half.pairs[(0, 1)].displacement_px == 4.0 and stats.pairs[(0, 1)].displacement_px == 8.0
