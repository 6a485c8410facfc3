"""``make bench-cameras --train``: the estimated training cameras brought into the dataset's
frame, so that the two runs differ only by the estimation's errors."""

from __future__ import annotations

import math
from types import SimpleNamespace

import numpy as np
import torch

from benchmarks.cameras import with_estimated_cameras
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
                                      fy=cam.fy * 1.1, cx=cam.cx, cy=cam.cy))  # fmt: skip
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
