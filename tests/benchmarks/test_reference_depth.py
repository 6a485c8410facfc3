"""Depth maps from a folder (bench-quality --depth-dir) and the all-view reference depth."""

from __future__ import annotations

from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest
import torch

from benchmarks.reference_depth import COVERED_ALPHA, reference_depths
from sparsesplat.engine.errors import PriorError
from sparsesplat.engine.priors import compute_priors
from sparsesplat.engine.priors.user import attach_depth_folder
from tests.engine.priors.synthetic import plane_scene


def test_depth_folder_becomes_the_user_prior(tmp_path: Path) -> None:
    scene, depths = plane_scene(seed=0)
    for view, depth in zip(scene.train, depths, strict=True):
        np.save(tmp_path / f"{view.name}.npy", depth.astype(np.float32))
    attached = attach_depth_folder(scene, tmp_path)
    assert all(v.depth is None for v in scene.train)  # the input scene is left as it was
    priors = compute_priors(attached, "user")
    for prior, depth in zip(priors, depths, strict=True):
        assert prior.metric
        assert torch.equal(prior.depth, torch.from_numpy(depth.astype(np.float32)))


def test_depth_folder_errors_name_the_view(tmp_path: Path) -> None:
    scene, depths = plane_scene(seed=0)
    np.save(tmp_path / "v0.npy", depths[0].astype(np.float32))
    with pytest.raises(PriorError, match="'v1'"):
        attach_depth_folder(scene, tmp_path)
    np.save(tmp_path / "v1.npy", depths[1][:-1].astype(np.float32))
    np.save(tmp_path / "v2.npy", depths[2].astype(np.float32))
    with pytest.raises(PriorError, match=r"v1\.npy: depth is \(71, 96\)"):
        attach_depth_folder(scene, tmp_path)


def test_reference_depth_is_alpha_normalised_and_filled_far() -> None:
    """Covered pixels: the blended depth divided by alpha; the rest: the farthest covered
    depth. Against a float64 computation of the same; float32 rounding is the only error."""
    gen = torch.Generator().manual_seed(0)
    true_z = 1.0 + 4.0 * torch.rand(1, 6, 8, generator=gen, dtype=torch.float64)
    alpha = torch.rand(1, 6, 8, generator=gen, dtype=torch.float64)
    alpha[0, 0, :3] = 0.0  # empty pixels: nothing rendered there
    render = SimpleNamespace(depth=(true_z * alpha).float(), alpha=alpha.float())
    trainer = SimpleNamespace(render=lambda camera: render)
    [(depth, covered)] = reference_depths(trainer, [SimpleNamespace(camera=None)])
    expect_covered = alpha[0] > COVERED_ALPHA
    assert torch.equal(covered, expect_covered)
    far = float(true_z[0][expect_covered].max())
    # float32 inputs: depth*alpha and alpha each carry a relative error of 2^-24
    assert torch.allclose(depth[covered].double(), true_z[0][covered], rtol=4e-7, atol=0)
    assert torch.allclose(depth[~covered].double(), torch.tensor(far).double(), rtol=4e-7)
    assert bool(torch.isfinite(depth).all())


@pytest.mark.shared_data
def test_all_view_scene_trains_on_every_protocol_view(shared_data: Path) -> None:
    from benchmarks.reference_depth import all_view_scene

    sparse, dense = all_view_scene(shared_data / "dtu" / "dtu_scan24")
    assert len(sparse.train) == 3 and len(dense.train) == 9 + 25
    assert len(set(dense.train_indices)) == len(dense.train_indices)
    assert set(sparse.train_indices) | set(sparse.test_indices) <= set(dense.train_indices)
    assert dense.test_indices == sparse.test_indices


def _fake_model(depth: torch.Tensor, alpha: torch.Tensor) -> SimpleNamespace:
    render = SimpleNamespace(depth=(depth * alpha)[None].float(), alpha=alpha[None].float())
    return SimpleNamespace(render=lambda camera: render)


@pytest.mark.parametrize("seed", [0, 1])
def test_held_out_geometry_against_the_reference(seed: int) -> None:
    """A model 10 % too far everywhere has relative error 0.1 and rank correlation 1; pixels
    one model leaves empty or outside the mask are not scored; covered counts the share."""
    from benchmarks.reference_depth import held_out_geometry

    gen = torch.Generator().manual_seed(seed)
    depth = 1.0 + 4.0 * torch.rand(20, 30, generator=gen, dtype=torch.float64)
    full = torch.ones(20, 30, dtype=torch.float64)
    holes = full.clone()
    holes[:5] = 0.0  # a quarter of the rows empty in the model
    reference = _fake_model(depth, full)
    view = SimpleNamespace(camera=None, mask=None)
    same = held_out_geometry(_fake_model(depth, full), reference, [view])
    assert same["abs_rel"] <= 1e-6 and same["rho"] == pytest.approx(1.0) and same["covered"] == 1
    far = held_out_geometry(_fake_model(depth * 1.1, holes), reference, [view])
    # float32 depth*alpha and alpha: relative error below 1e-6 on 1.1
    assert far["abs_rel"] == pytest.approx(0.1, abs=2e-6)
    assert far["rho"] == pytest.approx(1.0) and far["covered"] == pytest.approx(0.75)
    mask = torch.zeros(20, 30, dtype=torch.bool)
    mask[:10] = True  # half the reference's pixels, of which the model covers half
    masked = held_out_geometry(
        _fake_model(depth, holes), reference, [SimpleNamespace(camera=None, mask=mask)]
    )
    assert masked["covered"] == pytest.approx(0.5)
