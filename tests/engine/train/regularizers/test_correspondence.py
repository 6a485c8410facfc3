"""The matched-depth term: bilinear sampling against a float64 reference, the loss at the true
and at a wrong depth on an analytic plane, its gradient's direction, the opacity and schedule
gates, and the per-view targets against float64 projection.

Bounds: a sample at a pixel centre is computed from float32 grid coordinates ``2 x / W - 1``,
which grid_sample maps back to ``((g + 1) W - 1) / 2``; each step rounds once, so the sample
point is off the centre by at most ``4 u W`` pixels (u the float32 unit roundoff) and the value
by that times the largest difference to a neighbouring pixel.
"""

from __future__ import annotations

import numpy as np
import pytest
import torch

from sparsesplat.engine.camera import Camera
from sparsesplat.engine.train.config import CorrespondenceConfig
from sparsesplat.engine.train.init.matched_points import RunMatches
from sparsesplat.engine.train.loop.parts import TrainView
from sparsesplat.engine.train.loop.schedule import ScheduleClock
from sparsesplat.engine.train.regularizers.correspondence import (
    CorrespondenceTerm,
    matched_depth_loss,
    sample_at,
)
from tests.engine.numerics import UNIT_ROUNDOFF
from tests.engine.train.plane_scene import Plane, camera

U = UNIT_ROUNDOFF


def _bilinear64(image: torch.Tensor, xy: torch.Tensor) -> torch.Tensor:
    """(C, K) float64 bilinear samples, pixel centres at +0.5, border pixels repeated."""
    img = image.double()
    _, h, w = img.shape
    x = (xy[:, 0].double() - 0.5).clamp(0, w - 1)
    y = (xy[:, 1].double() - 0.5).clamp(0, h - 1)
    x0, y0 = x.floor().long().clamp(max=w - 2), y.floor().long().clamp(max=h - 2)
    fx, fy = x - x0, y - y0
    top = img[:, y0, x0] * (1 - fx) + img[:, y0, x0 + 1] * fx
    bottom = img[:, y0 + 1, x0] * (1 - fx) + img[:, y0 + 1, x0 + 1] * fx
    return top * (1 - fy) + bottom * fy


def test_samples_are_the_bilinear_interpolation_of_pixel_centres(seed: int) -> None:
    """At any point inside the outermost pixel centres, grid_sample's weights come from
    float32 coordinates: each weight is off by at most ~8 u W, so the sample by that times
    the largest pixel value (the values lie in [0, 1))."""
    g = torch.Generator().manual_seed(seed)
    h, w = 17, 23
    image = torch.rand(2, h, w, generator=g)
    xy = torch.rand(200, 2, generator=g) * torch.tensor([w - 1.0, h - 1.0]) + 0.5
    got = sample_at(image, xy).double()
    want = _bilinear64(image, xy)
    assert float((got - want).abs().max()) <= 16 * U * max(w, h)


def _plane_view(cam: Camera, plane: Plane, pixels: torch.Tensor) -> torch.Tensor:
    """World points (K, 3) float64 on ``plane`` behind the pixel centres ``pixels`` (K, 2)."""
    z = plane.depth(cam)[pixels[:, 1], pixels[:, 0]]
    u = pixels[:, 0].double() + 0.5
    v = pixels[:, 1].double() + 0.5
    local = torch.stack([(u - cam.cx) / cam.fx * z, (v - cam.cy) / cam.fy * z, z], dim=1)
    c2w = cam.camera_to_world.double()
    return local @ c2w[:3, :3].T + c2w[:3, 3]


def test_the_loss_is_zero_at_the_true_depth_and_the_excess_error_at_a_wrong_one(
    seed: int,
) -> None:
    g = torch.Generator().manual_seed(seed)
    cam, plane = camera((0.1, -0.2, 0.0)), Plane()
    depth = plane.depth(cam)
    alpha = 0.6 + 0.4 * torch.rand(depth.shape, generator=g, dtype=torch.float64)
    pixels = torch.stack(
        [
            torch.randint(0, cam.width, (50,), generator=g),
            torch.randint(0, cam.height, (50,), generator=g),
        ],
        dim=1,
    )
    xy = pixels.float() + 0.5
    target = depth[pixels[:, 1], pixels[:, 0]].float()
    rendered = (depth * alpha).float()[None]
    exact = matched_depth_loss(rendered, alpha.float()[None], xy, target, 0.01, 0.5)
    assert exact is not None and float(exact) == 0.0  # errors of ~1e-5 lie in the dead zone
    # 5 % too far everywhere: every pixel costs 0.05 - 0.01, up to the sampling error above
    # (relative, since depth and alpha are sampled alike) and float32 rounding of the ratio.
    wrong = (rendered * 1.05).requires_grad_(True)
    loss = matched_depth_loss(wrong, alpha.float()[None], xy, target, 0.01, 0.5)
    assert loss is not None
    step = float((depth[:, 1:] / depth[:, :-1] - 1).abs().max())
    bound = 1.05 * 16 * U * max(cam.width, cam.height) * step + 8 * U
    assert abs(float(loss.detach()) - 0.04) <= bound
    loss.backward()
    assert wrong.grad is not None
    grad = wrong.grad[0][pixels[:, 1], pixels[:, 0]]
    assert bool((grad > 0).all())  # descending moves the rendered depth back toward the point
    assert float(wrong.grad.abs().sum()) > 0


def test_pixels_without_opacity_are_skipped() -> None:
    depth = torch.full((1, 8, 8), 2.0)
    alpha = torch.full((1, 8, 8), 0.3)
    xy = torch.tensor([[3.5, 4.5], [1.5, 1.5]])
    target = torch.tensor([1.0, 1.0])
    assert matched_depth_loss(depth, alpha, xy, target, 0.0, 0.5) is None
    alpha[0, 4, 3] = 1.0  # one observation now sees a surface, at 2 against 1: error 1
    loss = matched_depth_loss(depth * alpha / 0.3, alpha, xy, target, 0.0, 0.5)
    assert loss is not None
    # The sample at (3.5, 4.5) is the centre of pixel (3, 4): depth 2 / 0.3 * 1 / 1 -> 2/0.3.
    assert float(loss) == pytest.approx(2.0 / 0.3 - 1.0, rel=1e-5)


def test_observations_beyond_max_error_are_skipped_but_stay_in_the_mean() -> None:
    """A truncated loss: an observation the render puts 50 % off costs nothing with
    ``max_error`` 0.2 (and sends no gradient), one 10 % off still costs its excess, and the
    mean is over both (skipping an outlier does not weigh the others more)."""
    depth = torch.full((1, 8, 8), 1.0)
    depth[0, 4, 3] = 1.1  # observation 0: 10 % too far
    depth[0, 1, 1] = 1.5  # observation 1: 50 % too far
    depth.requires_grad_(True)
    alpha = torch.ones(1, 8, 8)
    xy = torch.tensor([[3.5, 4.5], [1.5, 1.5]])
    target = torch.tensor([1.0, 1.0])
    plain = matched_depth_loss(depth, alpha, xy, target, 0.0, 0.5)
    assert plain is not None
    assert float(plain) == pytest.approx((0.1 + 0.5) / 2, rel=1e-5)
    cut = matched_depth_loss(depth, alpha, xy, target, 0.0, 0.5, max_error=0.2)
    assert cut is not None
    assert float(cut) == pytest.approx(0.1 / 2, rel=1e-4)
    cut.backward()
    assert depth.grad is not None
    assert float(depth.grad[0, 1, 1]) == 0.0  # the outlier pulls nothing
    assert float(depth.grad[0, 4, 3]) > 0.0


def _matches(
    cams: list[Camera], points: np.ndarray, angles: np.ndarray | None = None
) -> RunMatches:
    """Every point observed in every camera at its exact projection; ``angles``: the points'
    triangulation angles in degrees (default 90: the ``tolerance`` floor alone applies)."""
    point, view, xy = [], [], []
    for v, cam in enumerate(cams):
        w2c = cam.world_to_camera.double().numpy()
        local = points @ w2c[:3, :3].T + w2c[:3, 3]
        uv = np.stack(
            [
                cam.fx * local[:, 0] / local[:, 2] + cam.cx,
                cam.fy * local[:, 1] / local[:, 2] + cam.cy,
            ],
            axis=1,
        )
        point.append(np.arange(len(points)))
        view.append(np.full(len(points), v))
        xy.append(uv)
    return RunMatches(
        points.astype(np.float32),
        np.full((len(points), 3), 0.5, np.float32),
        np.full(len(points), 90.0, np.float32) if angles is None else angles.astype(np.float32),
        np.concatenate(point).astype(np.int64),
        np.concatenate(view).astype(np.int64),
        np.concatenate(xy).astype(np.float32),
        0.0,
        {},
    )


def test_targets_are_the_points_depths_in_each_camera_and_points_behind_are_dropped(
    seed: int,
) -> None:
    rng = np.random.default_rng(seed)
    cams = [camera((-0.3, 0.0, 0.0)).to("cpu", torch.float32), camera((0.4, 0.1, 0.0))]
    cams[1] = cams[1].to("cpu", torch.float32)
    points = rng.uniform([-1, -1, 3], [1, 1, 7], size=(40, 3))
    points[0] = (0.0, 0.0, -2.0)  # behind both cameras (a planted bad point)
    term = CorrespondenceTerm(
        CorrespondenceConfig(weight=1.0), _matches(cams, points), cams, ScheduleClock(100, None)
    )
    for v, cam in enumerate(cams):
        w2c = cam.world_to_camera.double().numpy()
        # The term uses the float32-stored points, so the reference does too.
        z = points.astype(np.float32).astype(np.float64) @ w2c[2, :3] + w2c[2, 3]
        want = z[z > 0]
        assert len(term.target[v]) == len(want) == 39
        np.testing.assert_allclose(term.target[v].numpy(), want, rtol=4 * U, atol=0)
    assert term.observations == 78


def test_the_schedule_and_views_without_observations_give_no_term() -> None:
    cam = camera((0.0, 0.0, 0.0)).to("cpu", torch.float32)
    points = np.array([[0.0, 0.0, 5.0], [0.3, -0.2, 4.0]])
    matches = _matches([cam], points)
    settings = CorrespondenceConfig(weight=2.0, start=10, until=20)
    term = CorrespondenceTerm(settings, matches, [cam, cam], ScheduleClock(100, None))
    h, w = cam.height, cam.width
    from sparsesplat.engine.raster import RasterOutput

    depth = torch.full((1, h, w), 5.0)
    out = RasterOutput(
        image=torch.zeros(3, h, w),
        depth=depth,
        alpha=torch.ones(1, h, w),
        radii=torch.zeros(0, dtype=torch.int32),
        means2d=torch.zeros(0, 2),
    )
    view0 = TrainView(0, cam, torch.zeros(3, h, w))
    assert term.extra_loss(10, out, view0) is None  # not after start yet
    assert term.extra_loss(20, out, view0) is None  # until reached
    loss = term.extra_loss(15, out, view0)
    # The second point is at depth 4 and rendered at 5: 0.25 - 0.01, weighted 2, over 2 points.
    assert loss is not None and float(loss) == pytest.approx(2.0 * (0.24 / 2), rel=1e-5)
    assert term.extra_loss(15, out, TrainView(1, cam, torch.zeros(3, h, w))) is None


def test_each_point_gets_the_dead_zone_of_its_triangulation_angle(seed: int) -> None:
    """tol = max(tolerance, pixel_error / (f tan a)) per observation, against float64."""
    rng = np.random.default_rng(seed)
    cams = [camera((-0.3, 0.0, 0.0)).to("cpu", torch.float32)]
    points = rng.uniform([-1, -1, 3], [1, 1, 7], size=(30, 3))
    angles = np.concatenate([rng.uniform(0.5, 60.0, size=25), rng.uniform(80.0, 89.0, size=5)])
    settings = CorrespondenceConfig(weight=1.0, tolerance=0.01, pixel_error=1.5)
    term = CorrespondenceTerm(settings, _matches(cams, points, angles), cams, ScheduleClock(10))
    a32 = angles.astype(np.float32).astype(np.float64)
    want = np.maximum(0.01, 1.5 / (cams[0].fx * np.tan(np.radians(a32))))  # f = 40 px here
    np.testing.assert_allclose(term.tolerance[0].numpy(), want, rtol=4 * U)
    assert (want > 0.01).any() and (want == 0.01).any()  # both regimes are exercised
