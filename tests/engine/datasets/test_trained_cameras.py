"""Uncertain training poses: ``rotation_std_deg`` in ``cameras.json``, the recipe that refines
them (``presets.pose_recipe``), and the cameras file written with the poses as trained."""

from __future__ import annotations

import dataclasses
import json
import math
from pathlib import Path
from typing import Any

import pytest
import torch

from sparsesplat.api.cameras import to_world_to_camera_opencv
from sparsesplat.engine.camera import Camera
from sparsesplat.engine.camera_convert import file_pose_from_w2c
from sparsesplat.engine.datasets import load_scene
from sparsesplat.engine.datasets.trained_cameras import folder_trained_cameras
from sparsesplat.engine.errors import SceneError
from sparsesplat.engine.train.config import PoseConfig
from sparsesplat.engine.train.config.presets import POSE_RECIPE, POSE_REFINE_MIN_STD_DEG
from sparsesplat.engine.train.run import RunSpec, plan_run
from tests.engine.datasets.synthetic import write_folder_scene


def _with_spreads(root: Path, spreads: list[float | None]) -> Path:
    """``root``'s cameras.json with frame i's ``rotation_std_deg`` set to ``spreads[i]``."""
    meta = json.loads((root / "cameras.json").read_text())
    for frame, spread in zip(meta["frames"], spreads, strict=True):
        if spread is not None:
            frame["rotation_std_deg"] = spread
    (root / "cameras.json").write_text(json.dumps(meta))
    return root


def _turned(camera: Camera, degrees: float) -> Camera:
    """``camera`` turned by ``degrees`` about its own y axis (world-to-camera, float64)."""
    a = math.radians(degrees)
    e = torch.eye(4, dtype=torch.float64)
    e[0, 0], e[0, 2], e[2, 0], e[2, 2] = math.cos(a), math.sin(a), -math.sin(a), math.cos(a)
    w2c = e @ camera.world_to_camera.double()
    return dataclasses.replace(camera, world_to_camera=w2c.float())


@pytest.mark.parametrize("convention", ["opencv", "opengl"])
@pytest.mark.parametrize("pose", ["camera_to_world", "world_to_camera"])
def test_the_engine_pose_goes_back_into_the_files_convention(convention: str, pose: str) -> None:
    c, s = math.cos(0.3), math.sin(0.3)
    matrix = [[c, 0.0, s, 1.0], [0.0, 1.0, 0.0, -2.0], [-s, 0.0, c, 0.5], [0.0, 0.0, 0.0, 1.0]]
    engine = torch.tensor(to_world_to_camera_opencv(matrix, convention, pose), dtype=torch.float64)
    back = file_pose_from_w2c(engine, convention, pose)
    assert all(
        math.isclose(a, b, abs_tol=1e-12)
        for r, q in zip(back, matrix, strict=True)
        for a, b in zip(r, q, strict=True)
    )


def test_the_scene_keeps_the_training_frames_largest_spread(tmp_path: Path) -> None:
    root = write_folder_scene(tmp_path / "s", count=5)  # frames 0-3 train, 4 held out
    assert load_scene(root).pose_std_deg is None  # no spread given: the poses are exact
    _with_spreads(root, [None, 0.2, 0.7, 0.4, 3.0])  # the held-out frame's does not count
    assert load_scene(root).pose_std_deg == 0.7


def test_a_negative_spread_is_refused_by_name(tmp_path: Path) -> None:
    root = _with_spreads(write_folder_scene(tmp_path / "s"), [-0.1, None, None, None])
    with pytest.raises(SceneError, match="rotation_std_deg"):
        load_scene(root)


@pytest.mark.parametrize(
    ("spread", "preset_name", "overrides", "refined"),
    [
        (None, None, {}, False),
        (POSE_REFINE_MIN_STD_DEG - 0.01, None, {}, False),
        (POSE_REFINE_MIN_STD_DEG, None, {}, True),
        (0.9, "llff", {}, True),  # a named preset: the cameras' fact still holds
        (0.9, None, {"poses.enabled": False}, False),  # the user's word wins
        (0.1, None, {"poses.enabled": True}, True),
    ],
)
def test_uncertain_training_poses_are_refined(
    tmp_path: Path, spread: float | None, preset_name: str | None, overrides: dict[str, Any],
    refined: bool,
) -> None:  # fmt: skip
    root = _with_spreads(write_folder_scene(tmp_path / "s"), [spread, None, None, None])
    plan = plan_run(RunSpec(preset_name, overrides), load_scene(root))
    assert plan.config.poses.enabled is refined
    recipe_said = bool(plan.notes)
    assert recipe_said is (refined and not overrides)
    if recipe_said:
        assert f"{spread:.2f}°" in plan.notes[0]
        assert plan.config.poses.lr == POSE_RECIPE["poses.lr"] != PoseConfig().lr
    else:
        assert plan.config.poses.lr == PoseConfig().lr


def test_an_override_of_a_recipe_setting_wins(tmp_path: Path) -> None:
    root = _with_spreads(write_folder_scene(tmp_path / "s"), [0.9, None, None, None])
    plan = plan_run(RunSpec(None, {"poses.lr": 5e-4}), load_scene(root))
    assert plan.config.poses.enabled and plan.config.poses.lr == 5e-4 and plan.notes


def test_the_trained_cameras_file_holds_the_refined_poses(tmp_path: Path) -> None:
    """Written in the upload's convention (OpenGL camera-to-world here) and read back by the
    folder loader, each training camera is the one trained; the held-out frame, the
    intrinsics and the images are the upload's, and the spread goes with the estimate."""
    root = write_folder_scene(tmp_path / "s", count=5)
    meta = json.loads((root / "cameras.json").read_text())
    meta["convention"] = "opengl"
    for frame in meta["frames"]:  # the same cameras in OpenGL axes
        c2w = torch.tensor(frame["matrix"], dtype=torch.float64)
        c2w[:3, 1:3] *= -1
        frame["matrix"] = c2w.tolist()
        frame["rotation_std_deg"] = 0.8
    (root / "cameras.json").write_text(json.dumps(meta))
    scene = load_scene(root)
    trained = [scene.train[0].camera] + [_turned(v.camera, 0.5) for v in scene.train[1:]]
    document = folder_trained_cameras(root, scene, trained)
    assert document["convention"] == "opengl" and document["pose"] == "camera_to_world"
    assert "rotation_std_deg" not in document["frames"][1]
    assert document["frames"][4] == meta["frames"][4]  # held out: untouched
    out = tmp_path / "out"
    out.mkdir()
    for frame in document["frames"]:
        (out / frame["image"]).write_bytes((root / frame["image"]).read_bytes())
    (out / "cameras.json").write_text(json.dumps(document))
    again = load_scene(out)
    for want, got in zip(trained, again.train, strict=True):
        assert torch.allclose(got.camera.world_to_camera, want.world_to_camera, atol=1e-6)
        assert (got.camera.fx, got.camera.cx) == (want.fx, want.cx)
    moved = again.train[1].camera.world_to_camera[:3, :3].double()
    given = scene.train[1].camera.world_to_camera[:3, :3].double()
    cos = float(((moved @ given.T).trace() - 1) / 2)
    assert math.degrees(math.acos(min(1.0, cos))) == pytest.approx(0.5, abs=1e-3)


def test_a_cameras_file_that_does_not_match_its_model_is_not_written(tmp_path: Path) -> None:
    root = write_folder_scene(tmp_path / "s", count=5)
    scene = load_scene(root)
    cameras = [v.camera for v in scene.train]
    with pytest.raises(SceneError, match="3 trained cameras for 4 training frames"):
        folder_trained_cameras(root, scene, cameras[:3])
    nan = dataclasses.replace(cameras[3], world_to_camera=torch.full((4, 4), math.nan))
    broken = [*cameras[:3], nan]
    with pytest.raises(SceneError, match="not finite"):
        folder_trained_cameras(root, scene, broken)
