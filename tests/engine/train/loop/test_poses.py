"""Training-camera refinement (``engine/train/loop/poses.py``): the algebra in float64, the
gradient's direction through the real rasterizer, the limits and the checkpoint state."""

from __future__ import annotations

import math

import pytest
import torch

from sparsesplat.engine.camera import Camera
from sparsesplat.engine.errors import TrainingDiverged
from sparsesplat.engine.raster import rasterize
from sparsesplat.engine.raster.projection import quat_to_rotmat
from sparsesplat.engine.train.config import PoseConfig
from sparsesplat.engine.train.loop.poses import PoseRefinement, matrix_to_quat
from sparsesplat.engine.train.loop.schedule import ScheduleClock
from tests.engine.numerics import UNIT_ROUNDOFF
from tests.engine.train.plane_scene import camera


def _random_rotation(g: torch.Generator) -> torch.Tensor:
    q = torch.randn(4, generator=g, dtype=torch.float64)
    return quat_to_rotmat(q)


def _rotation_about(axis: tuple[float, float, float], degrees: float) -> torch.Tensor:
    a = torch.tensor(axis, dtype=torch.float64)
    a = a / a.norm()
    half = math.radians(degrees) / 2
    return quat_to_rotmat(torch.cat([torch.tensor([math.cos(half)]), math.sin(half) * a]))


@pytest.mark.parametrize("case", ["random", "near_180", "identity"])
def test_matrix_to_quat_inverts_quat_to_rotmat(seed: int, case: str) -> None:
    g = torch.Generator().manual_seed(seed)
    if case == "random":
        r = _random_rotation(g)
    elif case == "near_180":  # trace near -1: the w component is ~0, the branch that divides
        r = _rotation_about(tuple(torch.randn(3, generator=g).tolist()), 179.999)
    else:
        r = torch.eye(4, dtype=torch.float64)[:3, :3]
    back = quat_to_rotmat(matrix_to_quat(r))
    # A few dozen roundings per entry, each at most the unit roundoff of values <= 1.
    assert torch.allclose(back, r, rtol=0, atol=64 * UNIT_ROUNDOFF)


def _refinement(cameras: list[Camera], **settings: float) -> PoseRefinement:
    return PoseRefinement(PoseConfig(enabled=True, **settings), cameras, 2.0, ScheduleClock(100))


def test_moving_the_gaussians_is_rendering_through_the_refined_camera(seed: int) -> None:
    """Camera-space centres and rotations of the moved Gaussians seen by the given camera equal
    those of the originals seen by the refined camera (float64, to rounding)."""
    g = torch.Generator().manual_seed(seed)
    cams = [camera((0.0, 0.0, 0.0)), camera((1.0, 0.2, 0.3)), camera((-0.8, 0.1, 0.5))]
    poses = _refinement(cams)
    with torch.no_grad():
        poses.rotation.copy_(0.02 * torch.randn(3, 3, generator=g, dtype=torch.float64))
        poses.translation.copy_(0.01 * torch.randn(3, 3, generator=g, dtype=torch.float64))
    means = torch.randn(50, 3, generator=g, dtype=torch.float64) + torch.tensor([0.0, 0.0, 5.0])
    quats = torch.randn(50, 4, generator=g, dtype=torch.float64)
    for i in range(3):
        moved_means, moved_quats = poses.move(i, means, quats)
        given, refined = cams[i].world_to_camera, poses.camera(i).world_to_camera
        seen_moved = moved_means @ given[:3, :3].T + given[:3, 3]
        seen_refined = means @ refined[:3, :3].T + refined[:3, 3]
        # Centres of size ~6 through three rigid maps: a few dozen roundings of that size.
        assert torch.allclose(seen_moved, seen_refined, rtol=0, atol=6 * 64 * UNIT_ROUNDOFF)
        rot_moved = given[:3, :3] @ quat_to_rotmat(moved_quats)
        rot_refined = refined[:3, :3] @ quat_to_rotmat(quats)
        assert torch.allclose(rot_moved, rot_refined, rtol=0, atol=64 * UNIT_ROUNDOFF)
    # The first camera fixes the frame: it is never corrected.
    assert torch.equal(poses.camera(0).world_to_camera, cams[0].world_to_camera)
    assert poses.move(0, means, quats)[0] is means


def _textured_cloud(g: torch.Generator, n: int = 600) -> tuple[torch.Tensor, ...]:
    """Small opaque Gaussians with random colours on a slanted slab in front of the cameras."""
    xy = (torch.rand(n, 2, generator=g) - 0.5) * torch.tensor([5.0, 4.0])
    z = 5.0 + 0.3 * xy[:, :1] + 0.4 * torch.rand(n, 1, generator=g)
    means = torch.cat([xy, z], dim=1)
    log_scales = torch.full((n, 3), math.log(0.08))
    quats = torch.tensor([[1.0, 0.0, 0.0, 0.0]]).repeat(n, 1)
    opacity = torch.full((n,), 3.0)
    colours = torch.rand(n, 3, generator=g)
    return means, log_scales, quats, opacity, colours


def test_the_gradient_brings_a_perturbed_camera_back(seed: int) -> None:
    """The photometric gradient through the real rasterizer, with the model fixed, turns a
    camera rotated by 1 degree back toward its true pose."""
    g = torch.Generator().manual_seed(seed)
    means, log_scales, quats, opacity, colours = _textured_cloud(g)
    true_cams = [camera((0.0, 0.0, 0.0), width=64, height=48, focal=50.0),
                 camera((0.6, 0.1, 0.0), width=64, height=48, focal=50.0)]  # fmt: skip
    true_cams = [c.to("cpu", torch.float32) for c in true_cams]
    target = rasterize(means, log_scales, quats, opacity, colours, true_cams[1]).image
    # The training camera is the true one turned by 1 degree about a tilted axis.
    wrong = torch.eye(4)
    wrong[:3, :3] = _rotation_about((0.3, 1.0, 0.2), 1.0).float()
    start = Camera(wrong @ true_cams[1].world_to_camera, *_intrinsics(true_cams[1]))
    poses = _refinement([true_cams[0], start], lr=2e-3)
    poses.clock.start(0.0)

    def error_deg() -> float:
        r = poses.camera(1).world_to_camera[:3, :3].double()
        rel = r @ true_cams[1].world_to_camera[:3, :3].double().T
        return math.degrees(math.acos(max(-1.0, min(1.0, (float(rel.trace()) - 1) / 2))))

    before = error_deg()
    for it in range(1, 101):
        moved_means, moved_quats = poses.move(1, means, quats)
        out = rasterize(moved_means, log_scales, moved_quats, opacity, colours, start)
        (out.image - target).abs().mean().backward()
        poses.step(it)
    assert before == pytest.approx(1.0, abs=1e-3)
    # 100 Adam steps of at most 2e-3 rad (0.11 degrees) each, decaying: the error must fall
    # well below the start; a gradient of the wrong sign would grow it instead.
    assert error_deg() < 0.3 * before


def _intrinsics(c: Camera) -> tuple[float, float, float, float, int, int]:
    return c.fx, c.fy, c.cx, c.cy, c.width, c.height


def test_a_correction_beyond_the_limit_stops_the_run_naming_the_camera() -> None:
    cams = [camera((0.0, 0.0, 0.0)), camera((1.0, 0.0, 0.0))]
    poses = _refinement(cams, max_rotation_deg=2.0)
    with torch.no_grad():
        poses.rotation[1] = torch.tensor([0.0, math.radians(1.9), 0.0], dtype=torch.float64)
    poses.check(7)  # under the limit: nothing
    with torch.no_grad():
        poses.rotation[1] = torch.tensor([0.0, math.radians(2.5), 0.0], dtype=torch.float64)
    with pytest.raises(TrainingDiverged, match="iteration 7: training camera 1's pose"):
        poses.check(7)
    with torch.no_grad():
        poses.rotation[1] = float("nan")
    with pytest.raises(TrainingDiverged, match="rotation is not finite"):
        poses.check(8)


def test_state_round_trips_and_the_first_camera_gets_no_step() -> None:
    cams = [camera((0.0, 0.0, 0.0)), camera((1.0, 0.0, 0.0))]
    poses = _refinement(cams)
    poses.clock.start(0.0)
    (poses.rotation.sum() + poses.translation.sum()).backward()
    poses.step(50)
    assert torch.all(poses.rotation[0] == 0) and torch.all(poses.translation[0] == 0)
    assert torch.all(poses.rotation[1] != 0)
    copy = _refinement(cams)
    copy.load_state_dict(poses.state_dict())
    assert torch.equal(copy.rotation, poses.rotation)
    assert (
        copy.optimizer.state_dict()["state"].keys() == poses.optimizer.state_dict()["state"].keys()
    )


def test_config_names_bad_values() -> None:
    from sparsesplat.engine.train.config import ConfigError

    with pytest.raises(ConfigError, match=r"poses\.start"):
        PoseConfig(start=1.0).validate()
    with pytest.raises(ConfigError, match=r"poses\.lr"):
        PoseConfig(lr=float("nan")).validate()
