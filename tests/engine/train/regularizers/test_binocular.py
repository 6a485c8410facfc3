"""Binocular self-consistency: the virtual camera's pose, the warp of a render through a zero
shift (the render itself), the loss on an analytic plane at the true and a planted wrong
depth, gradients into the virtual render and the geometry, and the part in the trainer (not
built when off; on, finite and drawing its shifts from the run's generator).

Bounds. With a zero shift every training pixel projects onto its own centre, up to the float32
roundings of the lift and projection (the warp-consistency tests' identity bound: 64 unit
roundoffs x the image size, in pixels), so the L1 is at most that offset x the largest step
between neighbouring pixels. On the plane at the true depth the warp is exact geometry, and
what remains is bilinear interpolation of a smooth image: on a unit cell its error is at most
(|f_uu| + |f_vv|) / 8 (bilinear reproduces the uv term exactly), bounded here by the image's
largest second differences (a smooth pattern whose period is >= 30 px: they match the second
derivatives to ~1 %, hence the factor 1.1).
"""

from __future__ import annotations

import math
from typing import Any

import pytest
import torch

from sparsesplat.engine.camera import Camera
from sparsesplat.engine.synthetic import make_scene
from sparsesplat.engine.train import Trainer
from sparsesplat.engine.train.regularizers.binocular import binocular_loss, shifted_camera
from tests.engine.numerics import UNIT_ROUNDOFF
from tests.engine.train.loop.test_trainer_parts import small
from tests.engine.train.plane_scene import Plane, camera

U = UNIT_ROUNDOFF


def _chw(image_hwc: torch.Tensor) -> torch.Tensor:
    return image_hwc.permute(2, 0, 1).contiguous().float()


@pytest.mark.parametrize("shift", [0.0, 0.3, -1.7])
def test_shifted_camera_moves_along_its_own_x_axis(shift: float) -> None:
    cam = camera((0.4, -0.2, 0.1), target=(1.0, 0.5, 5.0))
    moved = shifted_camera(cam, shift)
    x_axis = cam.world_to_camera[0, :3]  # the camera's +x in world coordinates
    assert torch.allclose(moved.center, cam.center + shift * x_axis, atol=1e-12)
    assert torch.equal(moved.world_to_camera[:3, :3], cam.world_to_camera[:3, :3])
    assert (moved.fx, moved.fy, moved.cx, moved.cy, moved.width, moved.height) == (
        cam.fx, cam.fy, cam.cx, cam.cy, cam.width, cam.height,
    )  # fmt: skip
    assert not torch.equal(moved.world_to_camera, cam.world_to_camera) or shift == 0.0


def _render(seed: int) -> tuple[Trainer, Any, Camera, tuple[torch.Tensor, ...]]:
    scene, depths = make_scene(seed=seed)
    t = Trainer(scene, small(seed=seed, **{"binocular.weight": 1.0}), depths)
    g, cam = t.gaussians, t.cameras[0]
    inputs = (g.means, g.log_scales, g.quats, g.opacity_logits, t.color.colors(g, cam.center))
    return t, t._raster(*inputs, cam, t.background), cam, inputs


def test_zero_shift_warps_a_render_onto_itself(seed: int) -> None:
    """d = 0: the virtual camera is the training camera, the virtual render is the render, and
    its warp through the render's own depth gives it back (the identity bound above)."""
    t, out, cam, inputs = _render(seed)
    virtual = shifted_camera(cam, 0.0)
    seen = t._raster(*inputs, virtual, t.background)
    assert torch.equal(seen.image, out.image)
    img = out.image.detach()
    loss = binocular_loss(img, seen.image, out.depth, out.alpha, cam, virtual)
    step = max(
        float((img[:, 1:] - img[:, :-1]).abs().max()),
        float((img[..., 1:] - img[..., :-1]).abs().max()),
    )
    offset = 64 * U * max(cam.width, cam.height)  # pixels
    assert float((out.alpha >= 0.5).sum()) > 0  # pixels do count
    assert float(loss.detach()) <= offset * step
    loss.backward()
    g = t.gaussians
    for p in (g.means, g.opacity_logits):
        assert p.grad is not None and bool(torch.isfinite(p.grad).all())


def _plane_case(shift: float) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor, Camera, Camera]:
    plane = Plane(period=4.0)  # ~6 px per unit at depth 5, focal 40: a 25 px period or more
    cam = camera((0.2, -0.1, 0.0)).to("cpu", torch.float32)
    virtual = shifted_camera(cam, shift)
    photo = _chw(plane.image(cam))
    render = _chw(plane.image(virtual)).requires_grad_(True)
    depth = plane.depth(cam).float()[None]
    return photo, render, depth, cam, virtual


def _interpolation_bound(image: torch.Tensor) -> float:
    """(|f_uu| + |f_vv|) / 8 over the image, from its second differences (x 1.1)."""
    fuu = (image[..., 2:] - 2 * image[..., 1:-1] + image[..., :-2]).abs().max()
    fvv = (image[:, 2:] - 2 * image[:, 1:-1] + image[:, :-2]).abs().max()
    return 1.1 * float(fuu + fvv) / 8


@pytest.mark.parametrize("shift", [0.6, -0.6])
def test_planted_depth_error_raises_the_loss(shift: float) -> None:
    """At the plane's true depth only interpolation error remains (the bound above); a depth
    15 % off moves every sample by 0.13 x the disparity (f d / z = 40 x 0.6 / 5 ~ 5 px: ~0.6
    px, a sizeable part of the pattern's slope) and the loss grows tenfold."""
    photo, render, depth, cam, virtual = _plane_case(shift)
    alpha = torch.ones_like(depth)
    at_true = binocular_loss(photo, render, depth, alpha, cam, virtual)
    bound = _interpolation_bound(render.detach())
    assert float(at_true.detach()) <= bound + 8 * U, (float(at_true), bound)
    at_wrong = binocular_loss(photo, render, depth * 1.15, alpha, cam, virtual)
    assert float(at_wrong.detach()) > 10 * float(at_true.detach()), (float(at_wrong), bound)


def test_gradients_reach_the_virtual_render_and_the_depth_and_are_finite() -> None:
    photo, render, depth, cam, virtual = _plane_case(0.6)
    depth = (depth * 1.05).requires_grad_(True)
    alpha = torch.full_like(depth, 0.9).requires_grad_(True)
    loss = binocular_loss(photo, render, depth * 0.9, alpha, cam, virtual)
    loss.backward()
    for x in (render, depth, alpha):
        assert x.grad is not None and bool(torch.isfinite(x.grad).all())
        assert float(x.grad.abs().sum()) > 0


def test_off_is_not_built_and_on_runs_finite(seed: int) -> None:
    scene, depths = make_scene(seed=seed)
    assert Trainer(scene, small(seed=seed), depths).binocular is None
    cfg = small(seed=seed, **{"binocular.weight": 1.0, "binocular.every": 2})
    t = Trainer(scene, cfg, depths)
    assert t.binocular is not None
    assert t.binocular.max_shift == pytest.approx(0.1 * t.extent)
    res = t.run()
    assert all(bool(torch.isfinite(v).all()) for v in t.gaussians.params.values())
    assert math.isfinite(res.metrics["psnr"])


def test_the_term_reaches_the_model_when_due(seed: int) -> None:
    t, out, cam, inputs = _render(seed)
    assert t.binocular is not None
    photo = t.images[0]
    assert t.binocular.extra_loss(1, inputs, out, cam, photo, t.background) is None  # <= start
    loss = t.binocular.extra_loss(2, inputs, out, cam, photo, t.background)
    assert loss is not None and float(loss.detach()) > 0
    loss.backward()
    g = t.gaussians
    for p in (g.means, g.opacity_logits, g.log_scales):
        assert p.grad is not None and bool(torch.isfinite(p.grad).all())
        assert float(p.grad.abs().sum()) > 0
