"""Near-plane pruning: the LLFF spiral path (against its closed form for axis-aligned input
cameras), the prune decision (against a direct float64 transcription, points kept away from
the decision boundary), the schedule, and the stiff cases."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest
import torch

from sparsesplat.engine.camera import Camera
from sparsesplat.engine.camera_path import llff_render_path, spiral_path
from sparsesplat.engine.datasets import load_scene
from sparsesplat.engine.errors import CameraError
from sparsesplat.engine.gaussians import Gaussians
from sparsesplat.engine.scene import Scene
from sparsesplat.engine.synthetic import make_scene
from sparsesplat.engine.train import preset
from sparsesplat.engine.train.config import ConfigError, NearPruneConfig
from sparsesplat.engine.train.loop.densify import ModelCollapsed
from sparsesplat.engine.train.regularizers.near_prune import (
    NearPrune,
    NearPruneSchedule,
    near_prune_mask,
)
from tests.engine.train.plane_scene import camera


def _axis_aligned_rig(seed: int, n: int = 12) -> torch.Tensor:
    """(n, 4, 4) OpenCV camera-to-world poses, identity rotation, random centres."""
    g = torch.Generator().manual_seed(seed)
    c2w = torch.eye(4, dtype=torch.float64).repeat(n, 1, 1)
    c2w[:, :3, 3] = torch.randn(n, 3, generator=g, dtype=torch.float64) * torch.tensor(
        [1.0, 0.6, 0.2], dtype=torch.float64
    )
    return c2w


def test_spiral_matches_its_closed_form_for_an_axis_aligned_rig(seed: int) -> None:
    """Identity rotations: the average frame is (x, -y, -z) at the mean centre m, so frame k is
    at m + (rx cos t, ry sin t, rz sin(t/2)), t = 4 pi k / 180, looking at m + (0, 0, focal),
    with r the 90th percentile of |centre - m| per axis (numpy's linear interpolation)."""
    c2w = _axis_aligned_rig(seed)
    near, far = 2.0, 40.0
    path = spiral_path(c2w, near, far)
    assert path.shape == (180, 4, 4) and path.dtype == torch.float64
    centres = c2w[:, :3, 3].numpy()
    m = centres.mean(0)
    r = np.percentile(np.abs(centres - m), 90, axis=0)
    focal = 1.0 / (0.25 / (0.9 * near) + 0.75 / (5.0 * far))
    t = np.linspace(0.0, 4 * math.pi, 180, endpoint=False)
    want = m + np.stack([r[0] * np.cos(t), r[1] * np.sin(t), r[2] * np.sin(t / 2)], axis=1)
    got = path[:, :3, 3].numpy()
    # Float64 all the way: the error is a few roundings of the largest coordinate involved.
    tol = 1e-12 * (1 + np.abs(centres).max() + focal)
    assert np.abs(got - want).max() < tol
    forward = path[:, :3, 2].numpy()
    aim = m + np.array([0.0, 0.0, focal]) - got
    aim /= np.linalg.norm(aim, axis=1, keepdims=True)
    assert np.abs(forward - aim).max() < tol
    rot = path[:, :3, :3]
    eye = torch.eye(3, dtype=torch.float64).expand_as(rot)
    assert float((rot.transpose(1, 2) @ rot - eye).abs().max()) < 1e-12
    assert bool((torch.linalg.det(rot) > 0).all())
    assert bool((path[:, 1, 1] > 0).all())  # image y (down) keeps pointing along world +y


def test_spiral_rejects_bad_input() -> None:
    c2w = _axis_aligned_rig(0)
    with pytest.raises(CameraError):
        spiral_path(c2w, 0.0, 10.0)
    with pytest.raises(CameraError):
        spiral_path(c2w[:, :3], 1.0, 10.0)
    bad = c2w.clone()
    bad[0, 0, 3] = math.nan
    with pytest.raises(CameraError):
        spiral_path(bad, 1.0, 10.0)
    opposed = c2w[:2].clone()
    opposed[1, :3, :3] = torch.diag(torch.tensor([-1.0, 1.0, -1.0], dtype=torch.float64))
    with pytest.raises(CameraError):  # forward axes cancel: no average viewing direction
        spiral_path(opposed, 1.0, 10.0)


@pytest.mark.shared_data
def test_llff_render_path_on_a_shared_scene(shared_data) -> None:  # type: ignore[no-untyped-def]
    """beer_can: 180 finite cameras whose centres stay within the spread of the real ones."""
    pb = np.load(shared_data / "nerf_llff_data" / "beer_can" / "poses_bounds.npy")
    h, w = float(pb[0, 4]), float(pb[0, 9])  # full-resolution height, width
    cams = llff_render_path(pb, (round(h / 8), round(w / 8)))
    assert len(cams) == 180
    centres = torch.stack([c.center.double() for c in cams])
    real = torch.tensor(pb[:, [3, 8, 13]], dtype=torch.float64)  # column 3 of the 3x5 matrix
    assert bool(torch.isfinite(centres).all())
    span = (real.max(0).values - real.min(0).values).norm()
    assert float((centres - real.mean(0)).norm(dim=1).max()) <= float(span)


def _brute_force(means: torch.Tensor, centres: torch.Tensor, near: float) -> torch.Tensor:
    d = ((means.double()[:, None, :] - centres.double()[None]) ** 2).sum(-1).sqrt()
    return (d < near).any(dim=1)


@pytest.mark.parametrize("chunk", [7, 65536])
def test_distance_mask_is_exactly_the_gaussians_within_near(seed: int, chunk: int) -> None:
    g = torch.Generator().manual_seed(seed)
    centres = torch.randn(30, 3, generator=g, dtype=torch.float64) * 3
    means = (torch.randn(2000, 3, generator=g) * 3).float()
    near = 1.0
    d = ((means.double()[:, None] - centres[None]) ** 2).sum(-1).sqrt()
    # Leave out points within float64 noise of the boundary (a tie is not a test).
    clear = ((d - near).abs() > 1e-9).all(dim=1)
    got = near_prune_mask(means, centres, near, chunk=chunk)
    want = _brute_force(means, centres, near)
    assert torch.equal(got[clear], want[clear])
    assert 0 < int(want.sum()) < len(means)  # both outcomes occur


def test_distance_mask_from_cameras_uses_their_centres() -> None:
    cams = [camera((0.0, 0.0, 0.0)), camera((5.0, 0.0, 0.0))]
    means = torch.tensor([[0.5, 0.0, 0.0], [4.0, 0.3, 0.0], [2.5, 0.0, 0.0], [0.0, 0.0, -0.9]])
    assert near_prune_mask(means, cams, 1.2).tolist() == [True, True, False, True]


def test_depth_mode_prunes_only_between_camera_and_near_plane() -> None:
    """Points in each camera's frame at z = near/2 (pruned), z = 1.5 near and z = -near/2
    (behind the camera, kept), also far off-axis."""
    cams = [camera((0.0, 0.0, 0.0)), camera((3.0, 1.0, 0.0), target=(3.0, 1.0, 10.0))]
    near = 0.8
    pts, want = [], []
    for cam in cams:
        c2w = cam.camera_to_world
        for x, y, z, pruned in [
            (0.0, 0.0, 0.4, True),
            (5.0, -3.0, 0.4, True),
            (0.0, 0.0, 1.2, False),
            (0.0, 0.0, -0.4, False),
        ]:
            pts.append(c2w[:3, :3] @ torch.tensor([x, y, z], dtype=torch.float64) + c2w[:3, 3])
            want.append(pruned)
    means = torch.stack(pts).float()
    got = near_prune_mask(means, cams, near, mode="depth")
    assert len(want) == 8
    # Each point is tested against both cameras: the rule over all of them decides.
    rows = torch.stack([c.world_to_camera[2] for c in cams])
    z = means.double() @ rows[:, :3].T + rows[:, 3]
    rule = ((z > 0) & (z < near)).any(dim=1)
    assert torch.equal(got, rule)
    for k, pruned in enumerate(want):
        if pruned:  # in front of its own camera, before the near plane: always pruned
            assert bool(got[k])


def test_stiff_cases() -> None:
    means = torch.randn(10, 3)
    assert not bool(near_prune_mask(means, [], 10.0).any())
    assert not bool(near_prune_mask(means, torch.zeros(1, 3), 0.0).any())
    assert near_prune_mask(torch.zeros(0, 3), torch.zeros(1, 3), 1.0).shape == (0,)
    # Everything within near: everything is pruned (the caller must handle an empty model).
    assert bool(near_prune_mask(means, means.double(), 1e9).all())
    with pytest.raises(CameraError):
        near_prune_mask(means, torch.zeros(1, 3), math.nan)
    with pytest.raises(CameraError):
        near_prune_mask(means, torch.zeros(1, 3), 1.0, mode="depth")


def test_schedule_follows_the_reference() -> None:
    s = NearPruneSchedule()
    due = [it for it in range(1, 2200) if s.due(it)]
    assert due[:3] == [2001, 2026, 2051]
    assert all((it - 1) % 25 == 0 for it in due)
    assert not s.due(2000) and not s.due(1)


def test_render_path_cameras_are_valid_cameras() -> None:
    """A synthetic poses_bounds (5 forward-facing views) round-trips into Camera objects."""
    rows = []
    for k in range(5):
        down, right, back = [0.0, -1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0]
        centre = [0.2 * k, 0.1 * (k % 2), 0.0]
        mat = np.array(
            [[down[i], right[i], back[i], centre[i], [378.0, 504.0, 400.0][i]] for i in range(3)]
        )
        rows.append(np.concatenate([mat.reshape(-1), [2.0, 30.0]]))
    cams = llff_render_path(np.stack(rows), (378, 504), n_frames=12)
    assert len(cams) == 12 and all(isinstance(c, Camera) for c in cams)
    for c in cams:
        r = c.world_to_camera[:3, :3].double()
        assert float((r @ r.T - torch.eye(3, dtype=torch.float64)).abs().max()) < 1e-6


# -- the training part -----------------------------------------------------------------------


def _part(scene: Scene, radius: float = 0.5, every: int = 25, after: int = 0) -> NearPrune:
    return NearPrune(NearPruneConfig(True, radius, start=after, every=every), scene)


def _model_near(centres: torch.Tensor, radius: float, seed: int) -> tuple[Gaussians, torch.Tensor]:
    """Gaussians half of which sit well inside ``radius`` of a centre (<= 0.5 radius), the
    other half well outside every centre (>= 1.5 radius); returns them and the inside mask."""
    g = torch.Generator().manual_seed(seed)
    n = 40
    inside = torch.arange(n) % 2 == 0
    pick = torch.randint(0, len(centres), (n,), generator=g)
    direction = torch.nn.functional.normalize(torch.randn(n, 3, generator=g, dtype=torch.float64))
    length = torch.rand(n, generator=g, dtype=torch.float64) * 0.5 * radius
    points = centres[pick] + direction * length[:, None]
    far = centres.mean(0) + torch.tensor([0.0, 0.0, 1.0], dtype=torch.float64) * 50.0 * radius
    points[~inside] = far + torch.randn(int((~inside).sum()), 3, generator=g, dtype=torch.float64)
    d_out = torch.cdist(points[~inside], centres).min(dim=1).values
    assert bool((d_out >= 1.5 * radius).all())  # the fixture keeps off the boundary
    return Gaussians.from_points(points.float(), 0.5, {}), inside


def test_part_prunes_exactly_the_rows_near_the_path_with_their_moments(seed: int) -> None:
    scene, _ = make_scene(seed=seed)
    part = _part(scene, radius=0.5, every=5, after=10)
    centres = torch.stack([v.camera.center.double() for v in scene.train])
    assert torch.equal(part.path_centres, centres)  # no render path: the training cameras
    model, inside = _model_near(centres, part.radius, seed)
    opt = torch.optim.Adam([{"params": [p], "name": k} for k, p in model.params.items()])
    model.means.grad = torch.ones_like(model.means)
    opt.step()
    moment = opt.state[model.means]["exp_avg"].clone()
    before = model.means.detach().clone()
    part.step(11, model, opt)  # (11 - 1) % 5 == 0 and 11 > 10: due
    assert torch.equal(model.means.detach(), before[~inside])
    assert torch.equal(opt.state[model.means]["exp_avg"], moment[~inside])
    assert part.pruned == int(inside.sum())
    for not_due in (10, 12, 5):
        part.step(not_due, *_model_near(centres, part.radius, seed)[:1], opt)
    assert part.pruned == int(inside.sum())


def test_render_path_replaces_the_training_cameras(seed: int) -> None:
    scene, _ = make_scene(seed=seed)
    path = [camera((float(x), 0.0, -3.0)) for x in range(-2, 3)]
    part = _part(dataclasses.replace(scene, render_path=path))
    want = torch.stack([c.center.double() for c in path])
    assert torch.equal(part.path_centres, want)
    assert part.radius == 0.5 * scene.near


def test_a_radius_that_covers_everything_is_a_clear_error() -> None:
    scene, _ = make_scene(seed=0)
    part = _part(scene, radius=1e6, every=1)
    model = Gaussians.from_points(torch.randn(10, 3), 0.5, {})
    with pytest.raises(ModelCollapsed, match=r"near_prune\.radius"):
        part.step(1, model, None)  # type: ignore[arg-type]


def test_eval_keep_leaves_out_what_is_near_the_rendered_cameras(seed: int) -> None:
    scene, _ = make_scene(seed=seed)
    part = _part(scene)
    cams = [v.camera for v in scene.test]
    centres = torch.stack([c.center.double() for c in cams])
    model, inside = _model_near(centres, part.radius, seed)
    assert torch.equal(part.eval_keep(model.means, cams), ~inside)


@pytest.mark.parametrize(
    ("field", "value"), [("near_prune.radius", 0.0), ("near_prune.radius", math.inf),
                         ("near_prune.every", 0)]
)  # fmt: skip
def test_bad_settings_are_config_errors(field: str, value: float) -> None:
    with pytest.raises(ConfigError, match=field):
        preset("llff", near_prune=True, **{field: value})
    with pytest.raises(ConfigError, match=field):  # the old flat name, same field
        preset("llff", near_prune=True, **{field.replace(".", "_"): value})


def test_start_is_compressed_with_the_schedule() -> None:
    cfg = preset("llff", near_prune=True).with_iterations(1500)
    assert cfg.near_prune.start == 500  # 2000 of 6000, scaled by 1500 / 6000


@pytest.mark.shared_data
def test_llff_loader_keeps_the_spiral_with_the_training_intrinsics(shared_data) -> None:  # type: ignore[no-untyped-def]
    scene = load_scene(shared_data / "nerf_llff_data" / "juicebox_table", views=3)
    assert len(scene.render_path) == 180
    ref = scene.train[0].camera
    for cam in scene.render_path[::45]:
        assert (cam.fx, cam.fy, cam.cx, cam.cy, cam.width, cam.height) == (
            ref.fx, ref.fy, ref.cx, ref.cy, ref.width, ref.height
        )  # fmt: skip
    centres = torch.stack([c.center.double() for c in scene.render_path])
    assert bool(torch.isfinite(centres).all())
