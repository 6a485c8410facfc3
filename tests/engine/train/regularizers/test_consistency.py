"""Warp consistency: identity warp, the warp of an analytic plane against float64 projection,
the loss at the true and a wrong depth, its gradient against finite differences (float64),
the occlusion and out-of-frame masks, and the stiff cases.

Coordinate bound (float32 warp vs float64 projection of the same float32 inputs): each source
camera coordinate ``q = R (z ray) + t`` carries at most ~8 roundings of its terms,
``E = 8 u (|R| |z ray| + |t|)``; then ``u_src = f q_x / q_z + c`` errs by at most
``f (E / q_z + |q_x| E / q_z^2) + 4 u |u_src|``. The cameras themselves are float32 (their
rounding is part of the inputs, so the reference uses the same float32 cameras).
"""

from __future__ import annotations

import math
from typing import Any

import pytest
import torch
from torch import Tensor

from sparsesplat.engine.camera import Camera
from sparsesplat.engine.errors import CameraError
from sparsesplat.engine.photometric.native import BACKEND_ENV
from sparsesplat.engine.train.regularizers.consistency import (
    warp_consistency_loss,
    warp_coordinates,
)
from tests.engine.numerics import UNIT_ROUNDOFF, assert_float32_close, compare_float32
from tests.engine.train.plane_scene import Plane, camera

U = UNIT_ROUNDOFF


def _f32(cam: Camera) -> Camera:
    return cam.to("cpu", torch.float32)


def _chw(image_hwc: torch.Tensor) -> torch.Tensor:
    return image_hwc.permute(2, 0, 1).contiguous()


def _pair() -> tuple[Plane, Camera, Camera]:
    return Plane(), _f32(camera((-0.3, 0.0, 0.0))), _f32(camera((0.35, 0.15, 0.05)))


def test_identity_warp_gives_zero_loss(seed: int) -> None:
    """Same camera, same photo, any positive depth: every pixel samples itself. The float32
    coordinates are within a few roundings of the pixel centre, so the loss is at most that
    offset times the largest neighbouring-pixel difference."""
    g = torch.Generator().manual_seed(seed)
    cam = _f32(camera((0.2, -0.1, 0.0)))
    img = torch.rand(3, cam.height, cam.width, generator=g)
    depth = (torch.rand(1, cam.height, cam.width, generator=g) * 5 + 0.5).requires_grad_(True)
    loss = warp_consistency_loss(img, img, depth, cam, cam)
    step = max(
        float((img[:, 1:] - img[:, :-1]).abs().max()),
        float((img[..., 1:] - img[..., :-1]).abs().max()),
    )
    offset = 64 * U * max(cam.width, cam.height)  # pixels
    assert float(loss.detach()) <= offset * step
    loss.backward()
    assert depth.grad is not None and bool(torch.isfinite(depth.grad).all())


@pytest.mark.parametrize("scale", [1.0, 1e3])
def test_plane_warp_matches_float64_projection(scale: float) -> None:
    """The reference pixels of a plane land where float64 projection of the same points puts
    them (scene and cameras scaled by ``scale``: the bound must follow)."""
    plane = Plane(offset=5.0 * scale, period=0.8 * scale)
    ref = _f32(camera((-0.3 * scale, 0.0, 0.0), target=(0.0, 0.0, 5.0 * scale)))
    src = _f32(camera((0.35 * scale, 0.15 * scale, 0.05 * scale), target=(0.0, 0.0, 5.0 * scale)))
    depth64 = plane.depth(ref)
    depth32 = depth64.float()
    u, v, z = warp_coordinates(depth32, ref, src)
    # float64 reference on the same float32 inputs (depth, cameras).
    w_ref, w_src = ref.world_to_camera.double(), src.world_to_camera.double()
    rel = w_src @ torch.linalg.inv(w_ref)
    vv, uu = torch.meshgrid(
        torch.arange(ref.height, dtype=torch.float64) + 0.5,
        torch.arange(ref.width, dtype=torch.float64) + 0.5,
        indexing="ij",
    )
    ray = torch.stack([(uu - ref.cx) / ref.fx, (vv - ref.cy) / ref.fy, torch.ones_like(uu)], -1)
    p = ray * depth32.double()[..., None]
    q = p @ rel[:3, :3].T + rel[:3, 3]
    u_ref = src.fx * q[..., 0] / q[..., 2] + src.cx
    v_ref = src.fy * q[..., 1] / q[..., 2] + src.cy
    big_e = 8 * U * (p.norm(dim=-1) + rel[:3, 3].norm())
    for got, want, num, f in ((u, u_ref, q[..., 0], src.fx), (v, v_ref, q[..., 1], src.fy)):
        bound = f * (big_e / q[..., 2] + num.abs() * big_e / q[..., 2] ** 2) + 4 * U * want.abs()
        err = (got.double() - want).abs()
        assert bool((err <= bound).all()), float((err / bound).max())
    assert float((z.double() - q[..., 2]).abs().max()) <= float((big_e).max())
    # The warp is exact geometry: the plane point seen in the source is the same plane point.
    depth_src = plane.depth(src)
    inside = (u_ref > 1) & (u_ref < src.width - 1) & (v_ref > 1) & (v_ref < src.height - 1)
    seen = torch.nn.functional.grid_sample(
        depth_src[None, None],
        torch.stack([u_ref / src.width * 2 - 1, v_ref / src.height * 2 - 1], -1)[None],
        align_corners=False,
    )[0, 0]
    # A plane's depth is linear in 1/z-space, not z: bilinear z interpolation errs by O(px^2).
    assert float(((seen - q[..., 2]) / q[..., 2])[inside].abs().max()) < 1e-3


def test_loss_is_small_at_the_true_depth_and_large_at_a_wrong_one() -> None:
    plane, ref, src = _pair()
    img_ref, img_src = _chw(plane.image(ref).float()), _chw(plane.image(src).float())
    true = plane.depth(ref).float()[None]
    at_true = float(warp_consistency_loss(img_ref, img_src, true, ref, src))
    at_wrong = float(warp_consistency_loss(img_ref, img_src, true * 1.15, ref, src))
    assert at_true < 0.02 and at_wrong > 5 * at_true, (at_true, at_wrong)


def test_gradient_matches_finite_differences_in_float64(seed: int) -> None:
    """d loss / d depth by autograd vs central differences, in float64 (bilinear sampling is
    piecewise smooth: a step that crosses a cell edge changes the slope, so the step is small
    and the check uses a handful of random pixels)."""
    plane = Plane()
    ref, src = camera((-0.3, 0.0, 0.0)), camera((0.35, 0.15, 0.05))  # float64 cameras
    img_ref, img_src = _chw(plane.image(ref)), _chw(plane.image(src))
    depth = (plane.depth(ref) * 1.03)[None].clone().requires_grad_(True)
    loss = warp_consistency_loss(img_ref, img_src, depth, ref, src)
    (grad,) = torch.autograd.grad(loss, depth)
    g = torch.Generator().manual_seed(seed)
    picks = torch.randint(0, ref.height * ref.width, (6,), generator=g)
    h = 1e-7
    for k in picks.tolist():
        r, c = divmod(k, ref.width)
        plus, minus = depth.detach().clone(), depth.detach().clone()
        plus[0, r, c] += h
        minus[0, r, c] -= h
        fd = (
            float(warp_consistency_loss(img_ref, img_src, plus, ref, src))
            - float(warp_consistency_loss(img_ref, img_src, minus, ref, src))
        ) / (2 * h)
        assert abs(float(grad[0, r, c]) - fd) <= 1e-5 * (abs(fd) + 1e-3), (r, c, fd)
    assert float(grad.abs().sum()) > 0


def test_alpha_normalises_depth_and_masks_thin_pixels() -> None:
    """Rendered depth is sum w z (not divided by alpha): with alpha 0.8 everywhere the loss at
    0.8 * z equals the loss at z; pixels below min_alpha do not count."""
    plane, ref, src = _pair()
    img_ref, img_src = _chw(plane.image(ref).float()), _chw(plane.image(src).float())
    z = plane.depth(ref).float()[None]
    alpha = torch.full_like(z, 0.8)
    a = warp_consistency_loss(img_ref, img_src, 0.8 * z, ref, src, alpha=alpha)
    b = warp_consistency_loss(img_ref, img_src, z, ref, src)
    assert abs(float(a) - float(b)) <= 1e-4
    none = warp_consistency_loss(img_ref, img_src, 0.8 * z, ref, src, alpha=alpha, min_alpha=0.9)
    assert float(none) == 0.0


def test_occlusion_check_ignores_pixels_the_source_sees_occluded() -> None:
    """Paint garbage into a block of the source photo and put an occluder there in the source
    depth: with the source depth given, the loss is as if the garbage were not there."""
    plane, ref, src = _pair()
    img_ref, img_src = _chw(plane.image(ref).float()), _chw(plane.image(src).float())
    true = plane.depth(ref).float()[None]
    src_depth = plane.depth(src).float()
    spoiled = img_src.clone()
    spoiled[:, 10:25, 15:35] = 1.0
    occluded = src_depth.clone()
    occluded[10:25, 15:35] = 0.5 * occluded[10:25, 15:35]
    clean = float(warp_consistency_loss(img_ref, img_src, true, ref, src, source_depth=src_depth))
    ignored = float(warp_consistency_loss(img_ref, spoiled, true, ref, src, source_depth=occluded))
    counted = float(warp_consistency_loss(img_ref, spoiled, true, ref, src, source_depth=src_depth))
    assert counted > 3 * clean
    assert ignored <= 1.5 * clean + 1e-3


def test_stiff_cases_are_finite_and_zero() -> None:
    plane, ref, src = _pair()
    img = _chw(plane.image(ref).float())
    img_src = _chw(plane.image(src).float())
    away = _f32(camera((0.0, 0.0, 0.0), target=(0.0, 0.0, -5.0)))
    true = plane.depth(ref).float()[None]
    cases = [
        (true.clone(), ref, away, None),  # source looks away: nothing in front of it
        (torch.zeros_like(true), ref, src, None),  # zero depth
        (torch.full_like(true, math.inf), ref, src, None),  # no surface
        (true.clone(), ref, src, torch.zeros_like(true)),  # alpha 0 everywhere
    ]
    for depth, r, s, alpha in cases:
        d = depth.requires_grad_(True)
        loss = warp_consistency_loss(img, img_src, d, r, s, alpha=alpha)
        assert float(loss.detach()) == 0.0
        loss.backward()
        assert d.grad is not None and bool(torch.isfinite(d.grad).all())
        assert float(d.grad.abs().sum()) == 0.0
    # Constant depth (a fronto-parallel wall) is an ordinary, finite case.
    wall = torch.full_like(true, 5.0).requires_grad_(True)
    loss = warp_consistency_loss(img, img_src, wall, ref, src)
    loss.backward()
    assert math.isfinite(float(loss.detach())) and bool(torch.isfinite(wall.grad).all())
    with pytest.raises(CameraError):
        warp_consistency_loss(img[:, :-1], img_src, true, ref, src)
    with pytest.raises(CameraError):
        warp_coordinates(true[0, :-1], ref, src)


# -- the native kernel (engine/photometric/cpu/warp.cpp) against the float64 reference --------


def _native_case(seed: int) -> dict[str, Any]:
    """float32 inputs on which every decision of the loss (alpha cut, in front, inside the
    source, occlusion, the sign of each colour difference) has a wide margin, so float32 and
    float64 take the same ones: alpha is 0.3 or in [0.6, 1]; the depth is the plane's within
    +-1 % (the occlusion tolerance is 5 %) and 0.5x in an occluder block of the source's depth;
    the source photo is affine in the pixel position (bilinear sampling is exact, its slope
    continuous across cells) and the reference photo 0.02 or 0.98, at least 0.1 from it."""
    g = torch.Generator().manual_seed(seed)
    plane, ref, src = _pair()
    h, w, hs, ws = ref.height, ref.width, src.height, src.width
    noise = 1.0 + 0.02 * (torch.rand(h, w, generator=g, dtype=torch.float64) - 0.5)
    z = (plane.depth(ref) * noise).float()
    alpha = torch.where(
        torch.rand(h, w, generator=g) < 0.2, 0.3, 0.6 + 0.4 * torch.rand(h, w, generator=g)
    )
    ys, xs = torch.meshgrid(
        torch.arange(hs, dtype=torch.float64) / hs,
        torch.arange(ws, dtype=torch.float64) / ws,
        indexing="ij",
    )
    src_img = torch.stack([0.2 + 0.6 * xs, 0.85 - 0.6 * ys, 0.15 + 0.3 * xs + 0.4 * ys]).float()
    ref_img = torch.where(torch.rand(3, h, w, generator=g) < 0.5, 0.02, 0.98)
    src_depth = plane.depth(src).float()
    src_depth[10:20, 12:26] *= 0.5
    return {
        "depth": (z * alpha)[None], "alpha": alpha[None], "ref_img": ref_img,
        "src_img": src_img, "src_depth": src_depth, "ref": ref, "src": src,
    }  # fmt: skip


def _loss_and_grads(case: dict[str, Any], dtype: torch.dtype) -> tuple[Tensor, Tensor, Tensor]:
    depth = case["depth"].detach().to(dtype).requires_grad_(True)
    alpha = case["alpha"].detach().to(dtype).requires_grad_(True)
    loss = warp_consistency_loss(
        case["ref_img"].to(dtype), case["src_img"].to(dtype), depth, case["ref"], case["src"],
        alpha=alpha, source_depth=case["src_depth"].to(dtype),
    )  # fmt: skip
    gd, ga = torch.autograd.grad(loss, (depth, alpha))
    return loss.detach(), gd, ga


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_native_warp_meets_the_float32_rule(seed: int, monkeypatch: pytest.MonkeyPatch) -> None:
    """The native pass (float32 CPU) against the torch implementation in float64 on the same
    float32 inputs, with torch's own float32 run as the scale of rounding (tests/engine/numerics):
    the loss and its gradients with respect to depth and alpha."""
    case = _native_case(seed)
    native = _loss_and_grads(case, torch.float32)
    ref64 = _loss_and_grads(case, torch.float64)
    monkeypatch.setenv(BACKEND_ENV, "torch")
    torch32 = _loss_and_grads(case, torch.float32)
    # Not vacuous: the occluder block leaves pixels out (gradient exactly zero there), and many
    # pixels count.
    d = case["depth"].clone().requires_grad_(True)
    warp_consistency_loss(
        case["ref_img"], case["src_img"], d, case["ref"], case["src"], alpha=case["alpha"]
    ).backward()
    assert d.grad is not None
    assert int((d.grad != 0).sum()) > int((ref64[1] != 0).sum()) + 20
    assert int((ref64[1] != 0).sum()) > 0.3 * ref64[1].numel()
    for name, got, ref, t32 in zip(
        ("loss", "d depth", "d alpha"), native, ref64, torch32, strict=True
    ):
        assert_float32_close(got, ref, t32, None, f"seed {seed}: {name}")
    # The rule catches one wrong gradient entry (1e-4 of the largest).
    wrong = native[1].clone()
    k = int(ref64[1].abs().argmax())
    wrong.view(-1)[k] += 1e-4 * float(ref64[1].abs().max())
    assert not compare_float32(wrong, ref64[1], torch32[1], None, "perturbed").passed


def test_native_and_torch_warps_agree_on_the_masks_and_stiff_cases(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    """Both paths count the same pixels (zero gradient exactly where the other has zero) and
    give an attached, finite zero when nothing qualifies."""
    case = _native_case(3)
    _, gd_native, _ = _loss_and_grads(case, torch.float32)
    monkeypatch.setenv(BACKEND_ENV, "torch")
    _, gd_torch, _ = _loss_and_grads(case, torch.float32)
    assert torch.equal(gd_native != 0, gd_torch != 0)
    monkeypatch.setenv(BACKEND_ENV, "native")
    d = torch.zeros_like(case["depth"]).requires_grad_(True)
    loss = warp_consistency_loss(case["ref_img"], case["src_img"], d, case["ref"], case["src"])
    assert float(loss.detach()) == 0.0
    loss.backward()
    assert d.grad is not None and float(d.grad.abs().sum()) == 0.0
