"""``make bench-cameras --train``: the estimated training cameras brought into the dataset's
frame, so that the two runs differ only by the estimation's errors."""

from __future__ import annotations

import dataclasses
import json
import math
from pathlib import Path
from types import SimpleNamespace
from typing import Any

import numpy as np
import pytest
import torch

from benchmarks import camera_photos, camera_training, cameras
from benchmarks.camera_training import seed_summary, with_estimated_cameras
from benchmarks.cameras import build_parser
from benchmarks.common import RESULTS_DIR_ENV
from sparsesplat.engine.match.geometry import PinholeArrays, project
from sparsesplat.engine.match.result import MatchSet
from sparsesplat.engine.match.settings import MatchSettings
from sparsesplat.engine.synthetic import make_scene


def _rotation(axis: np.ndarray, angle: float) -> np.ndarray:
    """Rodrigues: the rotation by ``angle`` radians about the unit ``axis``."""
    k = np.array([[0, -axis[2], axis[1]], [axis[2], 0, -axis[0]], [-axis[1], axis[0], 0]])
    return np.eye(3) + math.sin(angle) * k + (1 - math.cos(angle)) * k @ k


def _estimate(scene, rotation: np.ndarray, scale: float, shift: np.ndarray, tilt_deg: float):  # type: ignore[no-untyped-def]
    """An estimate of ``scene``'s training cameras in another frame (x_est = s R x + t), with
    the first camera turned by ``tilt_deg`` about its own y axis (a planted error)."""
    frames = []
    for i, view in enumerate(scene.train):
        w2c = view.camera.world_to_camera.double().numpy()
        r, centre = w2c[:3, :3], -w2c[:3, :3].T @ w2c[:3, 3]
        r_est = r @ rotation.T
        if i == 0:
            r_est = _rotation(np.array([0.0, 1.0, 0.0]), math.radians(tilt_deg)) @ r_est
        c_est = scale * rotation @ centre + shift
        est = np.eye(4)
        est[:3, :3], est[:3, 3] = r_est, -r_est @ c_est
        cam = view.camera
        frames.append(SimpleNamespace(matrix=np.linalg.inv(est).tolist(), fx=cam.fx * 1.1,
                                      fy=cam.fy * 1.1, cx=cam.cx, cy=cam.cy,
                                      rotation_std_deg=None if i == 0 else 0.25 * i))  # fmt: skip
    points = np.array([[0.1, 0.2, 0.3], [-0.2, 0.0, 0.5]])
    colours = np.full((2, 3), 0.5, dtype=np.float32)
    est_points = (scale * points @ rotation.T + shift).astype(np.float32)
    cameras = SimpleNamespace(frames=frames)
    return SimpleNamespace(cameras=cameras, points=est_points, colours=colours), points


def test_an_exact_estimate_in_another_frame_maps_back_onto_the_dataset_cameras() -> None:
    scene, _ = make_scene(seed=3)
    rotation = _rotation(np.array([2.0, -1.0, 0.5]) / math.sqrt(5.25), 0.7)
    estimate, points = _estimate(scene, rotation, 3.5, np.array([1.0, -2.0, 0.3]), 0.0)
    mapped, figures = with_estimated_cameras(scene, estimate, "cameras")
    assert figures["max_deg"] < 1e-5
    for old, new in zip(scene.train, mapped.train, strict=True):
        assert torch.allclose(new.camera.world_to_camera, old.camera.world_to_camera, atol=1e-5)
        assert new.camera.fx == old.camera.fx * 1.1  # the estimate's intrinsics are used
        assert torch.equal(new.image, old.image)
    assert mapped.test is scene.test  # held-out views and everything else stay the dataset's
    assert mapped.format == scene.format and mapped.near == scene.near
    assert mapped.sparse_points is not None
    assert np.allclose(mapped.sparse_points[0].numpy(), points, atol=1e-5)
    # The estimate's largest orientation spread, as the folder loader reads cameras.json.
    assert mapped.pose_std_deg == 0.25 * (len(scene.train) - 1) == figures["pose_std_deg"]


def test_a_planted_rotation_error_survives_the_mapping() -> None:
    """A camera turned 4 degrees in the estimate is 4 degrees off the dataset's after the
    mapping (minus what the alignment spreads over the others): the mapping does not hide an
    estimation error."""
    scene, _ = make_scene(seed=3)
    rotation = _rotation(np.array([0.0, 0.0, 1.0]), 0.3)
    estimate, _ = _estimate(scene, rotation, 0.5, np.zeros(3), 4.0)
    mapped, figures = with_estimated_cameras(scene, estimate, "cameras")
    assert 1.0 < figures["max_deg"] < 4.0 + 1e-6
    r_old = scene.train[0].camera.world_to_camera[:3, :3].double()
    r_new = mapped.train[0].camera.world_to_camera[:3, :3].double()
    angle = math.degrees(math.acos(min(1.0, (float(torch.trace(r_new.T @ r_old)) - 1) / 2)))
    assert 1.0 < angle < 4.0 + 1e-4


def _matches(scene, seed: int = 0) -> MatchSet:  # type: ignore[no-untyped-def]
    """Exact matches of the training photos: 60 points near the scene's centre seen by every
    camera, and 60 more seen by the second and third cameras only (the dataset's cameras)."""
    rng = np.random.default_rng(seed)
    cams = [PinholeArrays.of(v.camera) for v in scene.train]
    everyone, later = rng.uniform(-0.5, 0.5, (60, 3)), rng.uniform(-0.5, 0.5, (60, 3))
    keypoints = []
    for i, cam in enumerate(cams):
        points = np.concatenate([everyone, later]) if i else everyone
        uv, z = project(points, cam)
        assert (z > 0).all()
        keypoints.append(uv.astype(np.float32))
    first = np.arange(60, dtype=np.int32)
    both = np.arange(120, dtype=np.int32)
    rows = {(0, 1): np.stack([first, first], 1), (0, 2): np.stack([first, first], 1),
            (1, 2): np.stack([both, both], 1)}  # fmt: skip
    size = (scene.train[0].camera.width, scene.train[0].camera.height)
    return MatchSet(keypoints=keypoints, matches=rows,
                    scores={k: np.ones(len(v), np.float32) for k, v in rows.items()},
                    sizes=[size] * 3, settings=MatchSettings())  # fmt: skip


def test_the_scene_alignment_maps_an_exact_estimate_back() -> None:
    scene, _ = make_scene(seed=3)
    rotation = _rotation(np.array([2.0, -1.0, 0.5]) / math.sqrt(5.25), 0.7)
    estimate, points = _estimate(scene, rotation, 3.5, np.array([1.0, -2.0, 0.3]), 0.0)
    # The estimate's intrinsics are the dataset's here: the triangulation uses them.
    for frame, view in zip(estimate.cameras.frames, scene.train, strict=True):
        frame.fx, frame.fy = view.camera.fx, view.camera.fy
    mapped, figures = with_estimated_cameras(scene, estimate, "scene", _matches(scene))
    assert figures["alignment_points"] == 120
    assert figures["max_deg"] < 1e-5 and figures["cameras_max_deg"] < 1e-5
    for old, new in zip(scene.train, mapped.train, strict=True):
        assert torch.allclose(new.camera.world_to_camera, old.camera.world_to_camera, atol=1e-5)
    assert np.allclose(mapped.sparse_points[0].numpy(), points, atol=1e-5)


def test_the_scene_alignment_does_not_hide_a_planted_error() -> None:
    """One camera turned 4 degrees: the points it sees with the others no longer triangulate
    (the fit rests on the two exact cameras' own points), and under either fit some camera
    stays more than 2 degrees off, the issue's bar: three cameras share the error between
    them (a similarity absorbs part of it), but it shows."""
    scene, _ = make_scene(seed=3, width=160, height=120)  # 4 degrees: ~10 px
    rotation = _rotation(np.array([0.0, 0.0, 1.0]), 0.3)
    estimate, _ = _estimate(scene, rotation, 0.5, np.zeros(3), 4.0)
    for frame, view in zip(estimate.cameras.frames, scene.train, strict=True):
        frame.fx, frame.fy = view.camera.fx, view.camera.fy
    _, figures = with_estimated_cameras(scene, estimate, "scene", _matches(scene))
    assert figures["alignment_points"] == 60  # the second and third cameras' own points
    assert figures["max_deg"] > 2.0 and figures["cameras_max_deg"] > 2.0


def _row(run: str, seed: int, psnr: float, ssim: float, lpips: float) -> dict[str, Any]:
    return {"cameras": run, "seed": seed, "psnr": psnr, "ssim": ssim, "lpips": lpips}


def test_seeds_default_to_zero_alone_and_repeat_is_refused() -> None:
    parser = build_parser()
    assert parser.parse_args(["--train", "juicebox_table"]).seeds == [0]
    assert parser.parse_args(["--train", "juicebox_table", "--seeds", "1", "2"]).seeds == [1, 2]
    with pytest.raises(SystemExit):
        cameras.main(["--train", "juicebox_table", "--seeds", "1", "1"])


def test_the_seed_summary_averages_each_run_and_the_gap_per_seed() -> None:
    rows = [_row("dataset", 1, 17.0, 0.6, 0.37), _row("estimated", 1, 16.0, 0.5, 0.39),
            _row("dataset", 2, 17.5, 0.7, 0.36), _row("estimated", 2, 15.8, 0.5, 0.41),
            _row("refined", 2, 16.5, 0.55, 0.38)]  # fmt: skip
    summary = seed_summary(rows)
    dataset = summary["means"]["dataset"]
    assert dataset["seeds"] == [1, 2]
    assert dataset["psnr"] == pytest.approx(17.25) and dataset["lpips"] == pytest.approx(0.365)
    assert summary["means"]["refined"]["seeds"] == [2]
    gap = summary["psnr_gap"]["estimated"]
    assert gap["per_seed"] == {1: pytest.approx(-1.0), 2: pytest.approx(-1.7)}
    assert gap["mean"] == pytest.approx(-1.35)
    assert summary["psnr_gap"]["refined"] == {"per_seed": {2: pytest.approx(-1.0)},
                                              "mean": pytest.approx(-1.0)}  # fmt: skip
    assert "dataset" not in summary["psnr_gap"]
    assert "mean -1.35 dB" in camera_training.format_summary(summary)


def test_a_refined_run_counts_its_realigned_psnr_in_the_gap() -> None:
    """A run whose poses were refined is scored in its own frame (``realigned``); its raw
    PSNR, at held-out cameras placed for the unrefined ones, is not its gap."""
    refined = {**_row("estimated", 0, 14.0, 0.5, 0.4), "realigned": {"psnr": 16.8}}
    summary = seed_summary([_row("dataset", 0, 17.0, 0.6, 0.37), refined])
    assert summary["psnr_gap"]["estimated"]["per_seed"] == {0: pytest.approx(-0.2)}


@pytest.mark.parametrize(("seeds", "name"), [
    ([], "cameras-train-juicebox_table-given.json"),
    (["--seeds", "1", "2"], "cameras-train-juicebox_table-given-seeds-1-2.json"),
    (["--views", "5"], "cameras-train-juicebox_table-given-views-5.json"),
    (["--set", "poses.lr=0.001"], "cameras-train-juicebox_table-given-set.json"),
])  # fmt: skip
def test_main_hands_the_seeds_to_the_comparison_and_records_them(
    seeds: list[str], name: str, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """The training itself is replaced: what is checked is the plumbing, from the command line
    to :func:`train_comparison` and into the result file (summary only for several seeds)."""
    calls = []

    def fake(folder: Path, iterations: int | None, threads: int, given: bool,
             runs: tuple[str, ...], by: str, seeds: list[int],
             views: int | None, settings: dict[str, Any]) -> list[dict[str, Any]]:  # fmt: skip
        calls.append((runs, seeds, views, settings))
        return [_row(run, s, 17.0 - (run != "dataset"), 0.6, 0.4) for s in seeds for run in runs]

    monkeypatch.setattr(cameras, "train_comparison", fake)
    monkeypatch.setenv(RESULTS_DIR_ENV, str(tmp_path))
    argv = ["--data", str(tmp_path), "--train", "juicebox_table", "--given",
            "--runs", "dataset", "estimated", *seeds]  # fmt: skip
    assert cameras.main(argv) == 0
    expected = [int(s) for s in seeds[1:]] if seeds[:1] == ["--seeds"] else [0]
    views = int(seeds[1]) if seeds[:1] == ["--views"] else None
    settings = {"poses.lr": 0.001} if seeds[:1] == ["--set"] else {}
    assert calls == [(("dataset", "estimated"), expected, views, settings)]
    written = json.loads((tmp_path / name).read_text())
    assert written["seeds"] == expected
    assert written.get("settings", {}) == settings
    assert [(r["cameras"], r["seed"]) for r in written["rows"]] == [
        (run, s) for s in expected for run in ("dataset", "estimated")
    ]
    if len(expected) > 1:
        assert written["summary"]["psnr_gap"]["estimated"]["mean"] == pytest.approx(-1.0)
    else:
        assert "summary" not in written


def test_each_seed_trains_each_run_from_one_estimate(monkeypatch: pytest.MonkeyPatch) -> None:
    """:func:`train_comparison` with its training replaced: every (seed, run) pair is built
    with that seed, the estimate is made once, and each row names its seed."""
    from sparsesplat.engine import datasets
    from sparsesplat.engine.train import run as run_module

    dataset = SimpleNamespace(train=[0, 1, 2], test=[1, 2], name="dataset")
    estimated = SimpleNamespace(train=[0, 1, 2], test=[1, 2], name="estimated")
    estimates, built = [], []

    def fake_estimate(*args: Any) -> Any:
        estimates.append(args)
        return SimpleNamespace(photos=[SimpleNamespace(placed=True)] * 3)

    def fake_build_run(spec: Any, scene: Any, out_dir: Path) -> Any:
        built.append((spec.overrides["seed"], scene.name, spec.iterations))
        metrics = {"psnr": 10.0 + spec.overrides["seed"], "ssim": 0.5, "lpips": 0.3}
        result = SimpleNamespace(metrics=metrics, seconds=1.0)
        return SimpleNamespace(trainer=SimpleNamespace(run=lambda: result, poses=None))

    monkeypatch.setattr(datasets, "load_scene", lambda folder, views: dataset)
    monkeypatch.setattr(camera_training, "estimate_views", fake_estimate)
    monkeypatch.setattr(
        camera_training, "with_estimated_cameras", lambda *a: (estimated, {"x": 1.0})
    )
    monkeypatch.setattr(run_module, "build_run", fake_build_run)
    rows = camera_training.train_comparison(
        Path("scene"), 7, 1, True, ("dataset", "estimated"), "scene", [3, 5]
    )
    assert len(estimates) == 1
    assert built == [(3, "dataset", 7), (3, "estimated", 7), (5, "dataset", 7),
                     (5, "estimated", 7)]  # fmt: skip
    assert [(r["seed"], r["cameras"], r["psnr"]) for r in rows] == [
        (3, "dataset", 13.0), (3, "estimated", 13.0), (5, "dataset", 15.0),
        (5, "estimated", 15.0)]  # fmt: skip
    assert "x" in rows[1] and "x" not in rows[0]  # the estimate's figures on its runs only


def test_match_side_changes_only_the_learned_attempt() -> None:
    from sparsesplat.engine.sfm.attempts import ATTEMPTS

    assert camera_photos.attempts_matching_at(None) is ATTEMPTS
    moved = camera_photos.attempts_matching_at(640)
    assert [a.name for a in moved] == [a.name for a in ATTEMPTS]
    for old, new in zip(ATTEMPTS, moved, strict=True):
        expected = 640 if old.matcher is not None else None
        assert new.match_min_side == expected
        assert dataclasses.replace(new, match_min_side=None) == old
    assert any(a.match_min_side == 640 for a in moved)


def test_main_hands_the_match_side_to_each_estimate_and_names_the_file(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """The estimation itself is replaced: what is checked is the plumbing from the command
    line to :func:`measure`, into each row and into the result file's name."""
    calls = []

    def fake(
        folder: Path, given: bool, threads: int, match_side: int | None, scale: int
    ) -> dict[str, Any]:
        calls.append((folder.name, given, match_side))
        assert scale == 1
        return {"views": 3, "registered": 3, "outcome": "ok (learned)", "match_side": match_side}

    monkeypatch.setattr(cameras, "measure", fake)
    monkeypatch.setenv(RESULTS_DIR_ENV, str(tmp_path))
    argv = ["--data", str(tmp_path), "--scenes", "juicebox_table", "--match-side", "640"]
    assert cameras.main(argv) == 0
    assert calls == [("juicebox_table", False, 640), ("juicebox_table", True, 640)]
    written = json.loads((tmp_path / "cameras-match-side-640.json").read_text())
    assert [r["match_side"] for r in written["rows"]] == [640, 640]
    assert not (tmp_path / "cameras.json").exists()


def test_match_side_is_refused_with_train() -> None:
    with pytest.raises(SystemExit):
        cameras.main(["--train", "juicebox_table", "--match-side", "640"])


def test_photos_are_enlarged_by_the_scale_and_pixel_coordinates_scale_exactly(
    tmp_path: Path,
) -> None:
    """``--scale 2``: each photo written at twice its size, a block average of which gives the
    original back (bicubic keeps a linear ramp's means), so the intrinsics scale by 2."""
    from PIL import Image

    ramp = torch.linspace(0, 1, 24)[None, :, None].expand(16, 24, 3).contiguous()
    scene = SimpleNamespace(train=[SimpleNamespace(image=ramp)] * 2)
    (tmp_path / "a").mkdir()
    (tmp_path / "b").mkdir()
    (one, _) = camera_photos.write_training_photos(scene, tmp_path / "a")
    paths = camera_photos.write_training_photos(scene, tmp_path / "b", 2)
    assert [p.name for p in paths] == ["000.png", "001.png"]
    small = np.asarray(Image.open(one), dtype=np.float64)
    big = np.asarray(Image.open(paths[0]), dtype=np.float64)
    assert small.shape == (16, 24, 3) and big.shape == (32, 48, 3)
    means = big.reshape(16, 2, 24, 2, 3).mean(axis=(1, 3))
    # Inside the border a bicubic 2x of a linear ramp averages back to the ramp within the
    # 8-bit rounding of both images (0.5 each) and the kernel's overshoot at the clamped ends.
    assert np.abs(means[:, 2:-2] - small[:, 2:-2]).max() <= 1.0
    with pytest.raises(ValueError, match="scale"):
        camera_photos.write_training_photos(scene, tmp_path / "b", 0)


def test_scale_names_the_file_and_is_refused_with_train(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    scales = []

    def fake(
        folder: Path, given: bool, threads: int, match_side: Any, scale: int
    ) -> dict[str, Any]:
        scales.append(scale)
        return {"views": 3, "registered": 0, "seconds": 1.0, "outcome": "refused"}

    monkeypatch.setattr(cameras, "measure", fake)
    monkeypatch.setenv(RESULTS_DIR_ENV, str(tmp_path))
    assert cameras.main(["--data", str(tmp_path), "--scenes", "mic", "--scale", "2"]) == 0
    assert scales == [2, 2]
    assert (tmp_path / "cameras-scale-2.json").exists()
    assert not (tmp_path / "cameras.json").exists()
    for argv in (["--scale", "0"], ["--train", "mic", "--scale", "2"]):
        with pytest.raises(SystemExit):
            cameras.main(argv)


def test_a_comparison_trains_both_runs_on_the_placed_photos_only() -> None:
    """mic's 8 views with 4 placed: the dataset's run and the estimate's train on the same 4
    views (their indices kept), the held-out views untouched."""
    from sparsesplat.engine.scene import Scene

    scene = dataclasses.replace(make_scene(n_train=5)[0], train_indices=[10, 11, 12, 13, 14])
    flags = [True, False, True, True, False]
    estimate = SimpleNamespace(photos=[SimpleNamespace(placed=f) for f in flags])
    subset, placed = camera_photos.placed_views(scene, estimate)
    assert isinstance(subset, Scene) and placed == [0, 2, 3]
    assert [v.name for v in subset.train] == [scene.train[i].name for i in placed]
    assert subset.train_indices == [10, 12, 13] and subset.test == scene.test
    everything = SimpleNamespace(photos=[SimpleNamespace(placed=True)] * 5)
    assert camera_photos.placed_views(scene, everything) == (scene, [0, 1, 2, 3, 4])
