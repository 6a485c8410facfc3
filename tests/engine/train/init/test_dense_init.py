"""Dense initialisation: back-projection against an analytic plane, confidence selection,
photo-consistency, subsampling and the stiff cases (zero depth, cameras looking away).

Back-projection runs in float64 on the float32 depth; the bounds below are the float32
rounding of the input depth (|ray| |z| u per point) plus the rounding of the float32 output
(|X_k| u per coordinate), u = 2^-24.
"""

from __future__ import annotations

import math

import pytest
import torch

from sparsesplat.engine.camera import Camera, pixel_rays
from sparsesplat.engine.errors import PriorError
from sparsesplat.engine.priors.base import PriorDepth
from sparsesplat.engine.train.init.dense_init import (
    backproject,
    dense_points,
    dense_points_from_priors,
    photo_consistency,
)
from tests.engine.numerics import UNIT_ROUNDOFF
from tests.engine.train.plane_scene import Plane, camera

U = UNIT_ROUNDOFF


def _f32(cam: Camera) -> Camera:
    return cam.to("cpu", torch.float32)


def _reference_points(depth64: torch.Tensor, cam: Camera) -> torch.Tensor:
    """float64 back-projection X = C + R^T (z * ray), written independently of the module."""
    w2c = cam.world_to_camera.double()
    c2w = torch.linalg.inv(w2c)
    ray = pixel_rays(cam)
    cam_pts = ray * depth64[..., None]
    return cam_pts @ c2w[:3, :3].T + c2w[:3, 3]


@pytest.mark.parametrize(
    "eye", [(0.0, 0.0, 0.0), (1.5, -0.7, 0.4), (-2.0, 1.0, -1.0)], ids=["origin", "a", "b"]
)
def test_backprojected_plane_lies_on_the_plane(eye: tuple[float, float, float]) -> None:
    plane = Plane()
    cam = camera(eye)
    depth64 = plane.depth(cam)
    assert bool(torch.isfinite(depth64).all())
    depth32 = depth64.float()
    got = backproject(depth32, _f32(cam)).float()  # what dense_points returns
    ref = _reference_points(depth64, cam)
    # Distance to the plane of the float64 reference: float64 noise only.
    n = plane.normal / plane.normal.norm()
    on_plane = (ref @ n - plane.offset / plane.normal.norm()).abs()
    assert float(on_plane.max()) < 1e-12 * (1 + float(ref.abs().max()))
    # The camera pose itself was rounded to float32 by _f32: include that in the bound.
    w2c = cam.world_to_camera.double()
    pose_err = (w2c - w2c.float().double()).abs().max()
    ray_norm = pixel_rays(cam).norm(dim=-1)
    bound = (
        (
            ray_norm * depth64 * U  # rounding of the input depth
            + ref.abs().amax(dim=-1) * U  # rounding of the output
            + pose_err * (3 * ray_norm * depth64 + 3 * w2c[:3, 3].abs().max())  # pose rounding
        )
        * 1.01
    )
    err = (got.double() - ref).abs().amax(dim=-1)
    assert bool((err <= bound).all()), float((err / bound).max())


def test_constant_depth_gives_a_fronto_parallel_grid() -> None:
    """A constant depth map is the plane z = d in the camera: every point at view z = d."""
    cam = camera((0.3, 0.2, 0.1))
    d = 3.25
    pts = backproject(torch.full((cam.height, cam.width), d), cam)
    w2c = cam.world_to_camera.double()
    z = pts.reshape(-1, 3) @ w2c[2, :3] + w2c[2, 3]
    assert float((z - d).abs().max()) < 1e-12 * d * 10


def _index_image(cam: Camera, view: int) -> torch.Tensor:
    """Colours that encode the pixel: R = (u + 0.5) / W, G = (v + 0.5) / H, B = view / 4."""
    v, u = torch.meshgrid(
        torch.arange(cam.height, dtype=torch.float32),
        torch.arange(cam.width, dtype=torch.float32),
        indexing="ij",
    )
    b = torch.full_like(u, view / 4)
    return torch.stack([(u + 0.5) / cam.width, (v + 0.5) / cam.height, b], dim=-1)


def _random_confidence_views(
    seed: int,
) -> tuple[
    Plane, list[Camera], list[torch.Tensor], list[Camera], list[torch.Tensor], list[torch.Tensor]
]:
    """Two views of the plane with seeded uniform confidences: (plane, float64 cameras,
    index images, float32 cameras, depths, confidences)."""
    plane = Plane()
    cams = [camera((0.0, 0.0, 0.0)), camera((1.0, 0.5, 0.0))]
    g = torch.Generator().manual_seed(seed)
    depths = [plane.depth(c).float() for c in cams]
    confs = [torch.rand(c.height, c.width, generator=g) for c in cams]
    images = [_index_image(c, i) for i, c in enumerate(cams)]
    return plane, cams, images, [_f32(c) for c in cams], depths, confs


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_dense_points_keep_confident_pixels_and_their_colours(seed: int) -> None:
    """Only pixels at or above the confidence threshold come back, each with its own colour
    and its own back-projected point; the draw is ``target`` points, reproducible."""
    plane, cams, images, f32, depths, confs = _random_confidence_views(seed)
    pts, rgb, cut = dense_points(
        images, f32, depths, confs, 500, torch.Generator().manual_seed(seed)
    )
    assert cut == 0.5
    assert pts.shape == (500, 3) and rgb.shape == (500, 3)
    again = dense_points(images, f32, depths, confs, 500, torch.Generator().manual_seed(seed))
    assert torch.equal(pts, again[0]) and torch.equal(rgb, again[1])
    for k in range(500):
        view = round(float(rgb[k, 2]) * 4)
        cam = cams[view]
        u = round(float(rgb[k, 0]) * cam.width - 0.5)
        v = round(float(rgb[k, 1]) * cam.height - 0.5)
        assert float(confs[view][v, u]) >= 0.5
        want = _reference_points(plane.depth(cam), cam)[v, u]
        # Bound: input-depth rounding + output rounding + pose rounding, as above (loosely).
        tol = 64 * U * (1 + float(want.abs().max()) + float(plane.depth(cam)[v, u]))
        assert float((pts[k].double() - want).abs().max()) <= tol


def test_fewer_confident_pixels_than_target_returns_all() -> None:
    cam = camera((0.0, 0.0, 0.0))
    depth = Plane().depth(cam).float()
    conf = torch.zeros(cam.height, cam.width)
    conf[3, 4] = conf[10, 20] = 1.0
    pts, rgb, _ = dense_points(
        [_index_image(cam, 0)], [_f32(cam)], [depth], [conf], 100, torch.Generator()
    )
    assert pts.shape == (2, 3) and bool(torch.isfinite(pts).all())
    pixels = {(round(r * cam.width - 0.5), round(g * cam.height - 0.5)) for r, g, _ in rgb.tolist()}
    assert pixels == {(4, 3), (20, 10)}


def test_no_usable_pixel_raises_prior_error() -> None:
    """Zero depth, non-finite depth or zero confidence everywhere: a typed error, not NaNs."""
    cam = _f32(camera((0.0, 0.0, 0.0)))
    img = torch.rand(cam.height, cam.width, 3)
    ones = torch.ones(cam.height, cam.width)
    for depth, conf in [
        (torch.zeros(cam.height, cam.width), ones),
        (torch.full((cam.height, cam.width), math.nan), ones),
        (torch.full((cam.height, cam.width), 2.0), torch.zeros(cam.height, cam.width)),
    ]:
        with pytest.raises(PriorError):
            dense_points([img], [cam], [depth], [conf], 10, torch.Generator())
    with pytest.raises(PriorError):
        dense_points([img], [cam], [ones[:5]], [ones], 10, torch.Generator())


def test_floor_takes_the_most_confident_pixels_when_few_pass_the_cut() -> None:
    """Two pixels pass 0.7; a floor of 5 adds the next three most confident ones (never a
    zero-confidence pixel), the cut reported is the fifth's confidence, and the note says so.
    With enough pixels above the cut, the floor changes nothing."""
    cam = camera((0.0, 0.0, 0.0))
    depth = Plane().depth(cam).float()
    conf = torch.zeros(cam.height, cam.width)
    ranked = [((3, 4), 0.9), ((10, 20), 0.8), ((5, 5), 0.6), ((7, 1), 0.5), ((2, 9), 0.4)]
    for (v, u), c in ranked:
        conf[v, u] = c
    conf[8, 8] = 0.1  # the sixth: outside a floor of 5
    args = ([_index_image(cam, 0)], [_f32(cam)], [depth], [conf])
    pts, rgb, cut = dense_points(*args, 100, torch.Generator(), 0.7, min_points=5)
    assert pts.shape == (5, 3) and bool(torch.isfinite(pts).all())
    pixels = {(round(r * cam.width - 0.5), round(g * cam.height - 0.5)) for r, g, _ in rgb.tolist()}
    assert pixels == {(u, v) for (v, u), _ in ranked}
    assert cut == pytest.approx(0.4)
    drawn = dense_points(*args, 100, torch.Generator(), 0.7, min_points=5)
    assert drawn.describe(0.7) == "dense: 5 points (cut lowered 0.7 -> 0.4 to reach the floor)"
    # A floor above the usable pixels takes them all (6), still none of zero confidence.
    assert dense_points(*args, 100, torch.Generator(), 0.7, min_points=50).points.shape == (6, 3)
    # The floor is capped by the target: 3 points, the three most confident.
    few = dense_points(*args, 3, torch.Generator(), 0.7, min_points=5)
    assert few.points.shape == (3, 3) and few.cut == pytest.approx(0.6)
    # Enough above the cut: the same draw as without a floor, and the cut unchanged.
    plain = dense_points(*args, 100, torch.Generator(), 0.7)
    floored = dense_points(*args, 100, torch.Generator(), 0.7, min_points=2)
    assert torch.equal(plain.points, floored.points) and floored.cut == 0.7
    assert floored.describe(0.7) == "dense: 2 points"


@pytest.mark.parametrize("seed", [0, 1])
def test_floor_does_not_change_a_draw_that_meets_it(seed: int) -> None:
    """Many pixels above the cut: the floor leaves the seeded draw bit-identical (the
    forward-facing recipe's floor must not move its runs)."""
    _, _, images, f32, depths, confs = _random_confidence_views(seed)
    plain = dense_points(images, f32, depths, confs, 300, torch.Generator().manual_seed(seed), 0.7)
    floored = dense_points(
        images, f32, depths, confs, 300, torch.Generator().manual_seed(seed), 0.7, min_points=200
    )
    assert torch.equal(plain.points, floored.points) and torch.equal(plain.colours, floored.colours)
    assert floored.cut == 0.7


def test_negative_floor_is_a_prior_error() -> None:
    cam = _f32(camera((0.0, 0.0, 0.0)))
    ones = torch.ones(cam.height, cam.width)
    with pytest.raises(PriorError, match="min_points"):
        dense_points(
            [torch.rand(cam.height, cam.width, 3)],
            [cam],
            [ones],
            [ones],
            10,
            torch.Generator(),
            min_points=-1,
        )


def _two_views() -> tuple[Plane, list[Camera]]:
    return Plane(), [camera((-0.4, 0.0, 0.0)), camera((0.4, 0.1, 0.0))]


def test_photo_consistency_confirms_true_depth_and_rejects_wrong_depth() -> None:
    plane, cams = _two_views()
    images = [plane.image(c).float() for c in cams]
    true = [plane.depth(c).float() for c in cams]
    f32 = [_f32(c) for c in cams]
    conf = photo_consistency(images, f32, true)
    # Pixels whose plane point projects well inside the other view must be confirmed.
    for i, (c, other) in enumerate(zip(cams, reversed(cams), strict=True)):
        pts = _reference_points(plane.depth(c), c).reshape(-1, 3)
        w2c = other.world_to_camera.double()
        q = pts @ w2c[:3, :3].T + w2c[:3, 3]
        u = other.fx * q[:, 0] / q[:, 2] + other.cx
        v = other.fy * q[:, 1] / q[:, 2] + other.cy
        inner = (u > 2) & (u < other.width - 2) & (v > 2) & (v < other.height - 2)
        assert int(inner.sum()) > 0.5 * inner.numel()
        share = float(conf[i].reshape(-1)[inner].mean())
        assert share > 0.95, (i, share)
    wrong = [d * 1.3 for d in true]
    wrong_conf = photo_consistency(images, f32, wrong)
    for w in wrong_conf:
        assert float(w.mean()) < 0.05


def test_photo_consistency_with_a_camera_looking_away_is_all_zero() -> None:
    plane = Plane()
    cams = [camera((0.0, 0.0, 0.0)), camera((0.0, 0.0, 0.0), target=(0.0, 0.0, -5.0))]
    images = [plane.image(cams[0]).float(), torch.rand(36, 48, 3)]
    depths = [plane.depth(cams[0]).float(), torch.full((36, 48), 2.0)]
    conf = photo_consistency(images, [_f32(c) for c in cams], depths)
    for c in conf:
        assert bool(torch.isfinite(c).all()) and float(c.sum()) == 0.0


def test_priors_path_refuses_monocular_and_fills_flat_confidence() -> None:
    plane, cams = _two_views()
    images = [plane.image(c).float() for c in cams]
    f32 = [_f32(c) for c in cams]
    mono = [PriorDepth(plane.depth(c).float(), torch.ones(36, 48), False, "onnx") for c in cams]
    with pytest.raises(PriorError):
        dense_points_from_priors(images, f32, mono, 100, torch.Generator())
    # A user depth (confidence all ones) is checked by photo-consistency: a wrong depth keeps
    # few pixels, the true one many, on the plane.
    n_px = 2 * 36 * 48
    wrong = [
        PriorDepth(plane.depth(c).float() * 1.3, torch.ones(36, 48), True, "user") for c in cams
    ]
    try:
        n_wrong = dense_points_from_priors(images, f32, wrong, n_px, torch.Generator())[0].shape[0]
    except PriorError:
        n_wrong = 0
    good = [PriorDepth(plane.depth(c).float(), torch.ones(36, 48), True, "user") for c in cams]
    pts, _, _ = dense_points_from_priors(images, f32, good, 100, torch.Generator().manual_seed(0))
    assert pts.shape == (100, 3)
    n_good = dense_points_from_priors(images, f32, good, n_px, torch.Generator())[0].shape[0]
    assert n_wrong < 0.1 * n_good, (n_wrong, n_good)
    n = plane.normal / plane.normal.norm()
    dist = (pts.double() @ n - plane.offset / plane.normal.norm()).abs()
    assert float(dist.max()) < 64 * U * (1 + float(pts.abs().max()))
