"""Every scene in shared/data loads with its paper split."""

from __future__ import annotations

from pathlib import Path

import pytest
import torch

from sparsesplat.engine.datasets import detect_format, load_scene

SCENES = {
    "nerf_llff_data/juicebox_table": ("llff", (270, 480), 3, [1, 33, 63], 8),
    "nerf_llff_data/beer_can": ("llff", (640, 360), 3, [1, 35, 70], 9),
    "nerf_synthetic/mic": ("blender", (400, 400), 8, [26, 86, 2, 55, 75, 93, 16, 73], 25),
    "dtu/dtu_scan24": ("dtu", (300, 400), 3, [25, 22, 28], 25),
    "dtu/dtu_scan37": ("dtu", (300, 400), 3, [25, 22, 28], 25),
    "instant_ngp/fox": ("ngp", (960, 540), 3, [1, 33, 66], 9),
}


@pytest.mark.shared_data
@pytest.mark.parametrize("rel", sorted(SCENES))
def test_shared_scene_loads_with_paper_split(shared_data: Path, rel: str) -> None:
    fmt, hw, views, train_idx, n_test = SCENES[rel]
    assert detect_format(shared_data / rel) == fmt
    scene = load_scene(shared_data / rel)
    assert scene.format == fmt
    assert len(scene.train) == views and scene.train_indices == train_idx
    assert len(scene.test) == n_test == len(scene.test_indices)
    assert not set(scene.train_indices) & set(scene.test_indices) or fmt == "blender"
    for view in scene.train + scene.test[:2]:
        assert tuple(view.image.shape) == (*hw, 3) and view.image.dtype == torch.float32
        assert (view.camera.height, view.camera.width) == hw
        assert float(view.image.min()) >= 0.0 and float(view.image.max()) <= 1.0
        if fmt == "dtu":
            assert view.mask is not None and view.mask.shape == hw and view.mask.any()
    assert 0 < scene.near < scene.far
    assert scene.init_box is not None
    lo, hi = scene.init_box
    assert all(a < b for a, b in zip(lo, hi, strict=True))


@pytest.mark.shared_data
def test_blender_is_composited_on_white(shared_data: Path) -> None:
    scene = load_scene(shared_data / "nerf_synthetic/mic", views=2)
    corner = scene.train[0].image[:5, :5]
    assert torch.allclose(corner, torch.ones_like(corner)), "empty Blender pixels must be white"
    assert torch.equal(scene.background, torch.ones(3))


@pytest.mark.shared_data
def test_dtu_object_projects_inside_mask(shared_data: Path) -> None:
    scene = load_scene(shared_data / "dtu/dtu_scan24")
    for view in scene.train:
        cam = view.camera
        origin = cam.world_to_camera[:3, 3]  # the unit-sphere centre in camera coordinates
        u = int(cam.fx * origin[0] / origin[2] + cam.cx)
        v = int(cam.fy * origin[1] / origin[2] + cam.cy)
        assert view.mask is not None
        window = view.mask[max(0, v - 15) : v + 15, max(0, u - 15) : u + 15]
        assert window.any(), f"scene centre projects at ({u}, {v}) outside the mask of {view.name}"


@pytest.mark.shared_data
def test_views_parameter_and_downscale(shared_data: Path) -> None:
    scene = load_scene(shared_data / "dtu/dtu_scan37", views=6, downscale=2)
    assert scene.train_indices == [25, 22, 28, 40, 44, 48]
    assert tuple(scene.train[0].image.shape) == (150, 200, 3)
    assert scene.train[0].camera.width == 200 and scene.train[0].mask is not None
    assert abs(scene.train[0].camera.fx - 723.08 / 2) < 0.1
