"""The optional training parts wired into the loop (dropout, dense init, DTU background,
warp consistency): switched off they are not built; switched on they do what their module
says at trainer level, on tiny synthetic scenes."""

from __future__ import annotations

import dataclasses
import math
from pathlib import Path
from typing import Any

import pytest
import torch

from sparsesplat.engine.camera import Camera
from sparsesplat.engine.color.sh import C0
from sparsesplat.engine.model import raster as raster_module
from sparsesplat.engine.priors.base import PriorDepth
from sparsesplat.engine.raster import RasterOutput
from sparsesplat.engine.synthetic import look_at, make_scene
from sparsesplat.engine.train import Trainer, preset
from sparsesplat.engine.train.loop.parts import AuxiliaryStep
from sparsesplat.engine.train.regularizers.consistency import seen_depth, warp_consistency_loss


def small(**overrides: Any):  # type: ignore[no-untyped-def]
    """The LLFF recipe at smoke scale (as in test_trainer.py), from the random box (the
    preset's ``auto`` init is tested on its own below)."""
    base: dict[str, Any] = dict(
        init="random", iterations=30, init_points=200, eval_interval_s=0, eval_lpips=False,
        export=False, hash_log2_size=14, lr_means_start=0, lr_means_steps=30, soft_depth_start=10,
        densify_from=5, densify_until=25, densify_interval=5, depth_smooth_start=20,
        checkpoint_interval_s=0, threads=1,
    )  # fmt: skip
    base.update(overrides)
    return preset("llff", **base)


def _finite(t: Trainer) -> bool:
    return all(bool(torch.isfinite(v).all()) for v in t.gaussians.params.values())


def test_parts_switched_off_are_not_built() -> None:
    scene, priors = make_scene(seed=0)
    t = Trainer(scene, small(dropout=False), priors)
    assert t.dropout is None and t.init_note is None and t.dtu is None
    assert not t.depth.fill_background  # type: ignore[union-attr]


# -- dropout ---------------------------------------------------------------------------------


def _spy_rasterizer(
    monkeypatch: pytest.MonkeyPatch,
) -> tuple[list[tuple[int, bool]], dict[str, Trainer]]:
    """Record (rows rendered - model size, grad enabled) of every colour render of the
    trainer (depth-only renders, with 0 feature channels, are left out)."""
    calls: list[tuple[int, bool]] = []
    holder: dict[str, Trainer] = {}
    real = raster_module.rasterize

    def spy(means: torch.Tensor, *args: Any, **kwargs: Any) -> RasterOutput:
        t = holder.get("t")
        if t is not None and args[3].shape[-1] > 0:
            calls.append((means.shape[0] - len(t.gaussians), torch.is_grad_enabled()))
        return real(means, *args, **kwargs)

    # Before the trainer binds its rasterizer (engine/model/raster.py), so it binds the spy.
    monkeypatch.setattr(raster_module, "rasterize", spy)
    return calls, holder


@pytest.mark.parametrize("seed", [0, 1])
def test_dropout_stats_on_all_rows_and_evaluation_renders_all(
    monkeypatch: pytest.MonkeyPatch, seed: int
) -> None:
    scene, priors = make_scene(seed=seed)
    calls, holder = _spy_rasterizer(monkeypatch)
    t = Trainer(scene, small(seed=seed, dropout=True, dropout_rate=0.5, eval_every=10), priors)
    holder["t"] = t
    seen: list[tuple[int, int, int]] = []
    post = t.densify.step_post_backward  # type: ignore[union-attr]

    def check(it: int, g: Any, opt: Any, out: RasterOutput, *rest: Any) -> None:
        assert out.means2d.grad is not None
        seen.append((len(g), out.radii.shape[0], out.means2d.grad.shape[0]))
        post(it, g, opt, out, *rest)

    t.densify.step_post_backward = check  # type: ignore[union-attr,method-assign]
    res = t.run()
    assert seen and all(n == r == m for n, r, m in seen)
    assert _finite(t) and math.isfinite(res.metrics["psnr"])
    # Some photometric renders dropped rows; no render without gradients (evaluation) did.
    assert any(d < 0 for d, grad in calls if grad)
    assert all(d == 0 for d, grad in calls if not grad)


def test_dropout_that_keeps_nothing_renders_everything(monkeypatch: pytest.MonkeyPatch) -> None:
    scene, priors = make_scene(seed=2)
    calls, holder = _spy_rasterizer(monkeypatch)
    cfg = small(iterations=12, dropout=True, dropout_rate=0.999999, dropout_progressive=False)
    t = Trainer(scene, cfg, priors)
    holder["t"] = t
    before = t.gaussians.means.detach().clone()
    t.run()
    assert _finite(t) and not torch.equal(before, t.gaussians.means.detach()[: len(before)])
    # At this rate (almost) every draw keeps nothing: those photometric renders use all rows.
    photometric = [d for d, grad in calls if grad]
    assert len(photometric) == 12 and sum(d == 0 for d in photometric) >= 10


# -- dense init ------------------------------------------------------------------------------


def _true_depth_priors(scene: Any, depths: list[torch.Tensor]) -> list[PriorDepth]:
    """The synthetic scene's true depth as metric priors, trusted where the image shows the
    blob (not the black background)."""
    out = []
    for v, d in zip(scene.train, depths, strict=True):
        conf = (v.image.amax(dim=-1) > 0.05).float()
        out.append(PriorDepth(d.float(), conf, metric=True, kind="true"))
    return out


def _on_surface_fraction(points: torch.Tensor, scene: Any, depths: list[torch.Tensor]) -> float:
    """Fraction of points within 2% of the true depth of the blob in some training view."""
    near = torch.zeros(len(points), dtype=torch.bool)
    for v, d in zip(scene.train, depths, strict=True):
        cam = v.camera
        w2c = cam.world_to_camera.float()
        q = points @ w2c[:3, :3].T + w2c[:3, 3]
        z = q[:, 2]
        u = (cam.fx * q[:, 0] / z + cam.cx).floor().long()
        r = (cam.fy * q[:, 1] / z + cam.cy).floor().long()
        inside = (z > 0) & (u >= 0) & (u < cam.width) & (r >= 0) & (r < cam.height)
        ui, ri = u.clamp(0, cam.width - 1), r.clamp(0, cam.height - 1)
        fg = v.image.amax(dim=-1)[ri, ui] > 0.05
        near |= inside & fg & ((z - d[ri, ui]).abs() <= 0.02 * d[ri, ui])
    return float(near.float().mean())


@pytest.mark.parametrize("seed", [0, 1])
def test_dense_init_points_lie_on_the_surface(tmp_path: Path, seed: int) -> None:
    scene, depths = make_scene(seed=seed, width=40, height=30)
    metric = _true_depth_priors(scene, depths)
    dense = Trainer(
        scene, small(init="dense", dense_init_points=150), depths, tmp_path, init_depth=metric
    )
    assert len(dense.gaussians) == 150
    assert dense.init_note == "dense: 150 points"
    random_init = Trainer(scene, small(), depths)
    pts = dense.gaussians.means.detach()
    assert _on_surface_fraction(pts, scene, depths) > 0.95
    assert _on_surface_fraction(random_init.gaussians.means.detach(), scene, depths) < 0.3
    res = dense.run()
    assert res.metrics["init"] == "dense: 150 points" and _finite(dense)


def test_dense_init_floor_reaches_below_the_cut_and_says_so(tmp_path: Path) -> None:
    """Every blob pixel at confidence 0.5, the cut at 0.7: without a floor nothing passes and
    the run falls back to the random box; with a floor of 120 the run starts from 120 blob
    pixels and its ``init`` note names the lowered cut."""
    scene, depths = make_scene(seed=0, width=40, height=30)
    half = [dataclasses.replace(p, confidence=p.confidence * 0.5) for p in
            _true_depth_priors(scene, depths)]  # fmt: skip
    strict = {"init.dense_min_confidence": 0.7}
    none = Trainer(scene, small(init="dense", dense_init_points=150, **strict), depths,
                   init_depth=half)  # fmt: skip
    assert none.init_note is not None and none.init_note.startswith("random: dense init failed")
    floored = Trainer(
        scene,
        small(init="dense", dense_init_points=150, **strict, **{"init.dense_min_points": 120}),
        depths,
        tmp_path,
        init_depth=half,
    )
    assert len(floored.gaussians) == 120
    assert floored.init_note == "dense: 120 points (cut lowered 0.7 -> 0.5 to reach the floor)"
    assert _on_surface_fraction(floored.gaussians.means.detach(), scene, depths) > 0.95


def test_dense_init_sh_colours_from_pixels() -> None:
    scene, depths = make_scene(seed=2)
    metric = _true_depth_priors(scene, depths)
    cfg = small(init="dense", dense_init_points=100, color_model="sh")
    t = Trainer(scene, cfg, depths, init_depth=metric)
    rgb = t.gaussians.params["sh_dc"][:, 0].detach() * C0 + 0.5
    pixels = torch.cat([v.image[(v.image.amax(dim=-1) > 0.05)] for v in scene.train])
    # Every initial colour is one of the confident pixels' colours.
    dist = torch.cdist(rgb.double(), pixels.double()).min(dim=1).values
    assert bool((dist < 1e-5).all())


def test_dense_init_without_confident_pixel_falls_back_to_random(tmp_path: Path) -> None:
    scene, depths = make_scene(seed=3)
    invalid = [PriorDepth(torch.full_like(d, -1.0), (d > 0).float(), True) for d in depths]
    t = Trainer(scene, small(init="dense"), depths, tmp_path, init_depth=invalid)
    assert len(t.gaussians) == 200 and t.init_note is not None
    assert t.init_note.startswith("random: dense init failed")
    res = t.run()
    assert res.metrics["init"].startswith("random") and _finite(t)


def test_dense_init_computes_plane_sweep_when_the_prior_is_not_metric(tmp_path: Path) -> None:
    scene, depths = make_scene(seed=4, width=40, height=30)
    t = Trainer(scene, small(init="dense", dense_init_points=100, iterations=3), depths, tmp_path)
    assert t.init_note is not None  # dense or, when the sweep trusts nothing, the fallback
    assert (tmp_path / "priors").is_dir()  # the plane-sweep prior is cached for a resume


# -- DTU background --------------------------------------------------------------------------


def test_dtu_alpha_pass_changes_only_opacities_and_lowers_background_alpha() -> None:
    scene, depths = make_scene(seed=0)
    t = Trainer(scene, small(dtu_background=True), depths)
    assert t.dtu is not None
    view = t.dtu.adjust_view(t._next_view())
    assert view.mask is not None and bool(view.mask.any()) and not bool(view.mask.all())
    assert bool((view.image[:, view.mask] == 0).all())

    def bg_alpha() -> float:
        out = t.render(view.camera)
        return float(out.alpha[0][view.mask].square().mean())

    before = {k: v.detach().clone() for k, v in t.gaussians.params.items()}
    a0 = bg_alpha()
    for _ in range(5):
        t.dtu.step_pre_photometric(
            AuxiliaryStep(1, t.gaussians, t.optimizer, view, t.extent, t.guard, t.timer)
        )
    after = t.gaussians.params
    for k, v in before.items():
        assert torch.equal(v, after[k].detach()) == (k != "opacity_logits"), k
    assert bg_alpha() < a0


def test_dtu_run_applies_the_black_white_rule_at_each_densification() -> None:
    scene, depths = make_scene(seed=1)
    t = Trainer(scene, small(dtu_background=True), depths)
    assert t.dtu is not None
    calls: list[int] = []
    rule = t.dtu.black_white

    def spy(it: int, g: Any, colors: torch.Tensor) -> None:
        assert colors.shape == (len(g), 3)
        calls.append(it)
        rule(it, g, colors)

    t.dtu.black_white = spy  # type: ignore[method-assign]
    res = t.run()
    assert calls == [10, 15, 20] and _finite(t) and math.isfinite(res.metrics["psnr"])


def test_dtu_sub_switches_off_leave_only_the_mask() -> None:
    scene, depths = make_scene(seed=1)
    off = dict(dtu_blacken_target=False, dtu_alpha_loss=False, dtu_black_white=False)
    t = Trainer(scene, small(dtu_background=True, **off), depths)
    assert t.dtu is not None
    assert t.dtu.densify_rule(1, lambda g: t.color.colors(g, t.cameras[0].center)) is None
    view = t.dtu.adjust_view(t._next_view())
    assert torch.equal(view.image, t.images[view.index]) and view.mask is not None


@pytest.mark.parametrize("fill", [0.0, 1.0])
def test_dtu_all_background_and_no_background_views_stay_finite(fill: float) -> None:
    # All black: every pixel is background (constant depth maps, alpha pushed to 0 everywhere);
    # all white: no background (the alpha pass is skipped, the depth left unchanged).
    scene, depths = make_scene(seed=3, image_fill=fill)
    t = Trainer(scene, small(dtu_background=True, iterations=20, densify_from=3), depths)
    t.run()
    assert _finite(t)


# -- warp consistency ------------------------------------------------------------------------


@pytest.mark.parametrize("seed", [0, 1])
def test_consistency_term_reaches_the_geometry_and_the_run_is_finite(seed: int) -> None:
    scene, depths = make_scene(seed=seed)
    t = Trainer(scene, small(seed=seed, consistency_weight=0.5, consistency_start=0), depths)
    assert t.consistency is not None
    partners = t.consistency.partners
    assert all(len(p) == 1 and p[0] != i for i, p in enumerate(partners))
    view = t._next_view()
    g = t.gaussians
    out = t._raster(
        g.means, g.log_scales, g.quats, g.opacity_logits,
        t.color.colors(g, view.camera.center), view.camera, t.background,
    )  # fmt: skip
    assert t.consistency.extra_loss(0, g, out, view) is None  # not after consistency_start
    loss = t.consistency.extra_loss(1, g, out, view)
    assert loss is not None and float(loss.detach()) > 0
    loss.backward()
    assert g.means.grad is not None and float(g.means.grad.abs().sum()) > 0
    t.optimizer.zero_grad(set_to_none=True)
    res = t.run()
    assert _finite(t) and math.isfinite(res.metrics["psnr"])


@pytest.mark.parametrize("seed", [0, 1])
def test_consistency_with_all_partners_is_the_mean_over_the_other_views(seed: int) -> None:
    scene, depths = make_scene(seed=seed, n_train=3)
    cfg = small(seed=seed, consistency_weight=0.5, consistency_start=0, consistency_partners="all")
    t = Trainer(scene, cfg, depths)
    assert t.consistency is not None
    nearest = Trainer(scene, small(seed=seed, consistency_weight=0.5), depths).consistency
    assert nearest is not None
    for i, p in enumerate(t.consistency.partners):
        assert sorted(p) == [j for j in range(3) if j != i]
        assert p[0] == nearest.partners[i][0]  # nearest first
    view = t._next_view()
    g = t.gaussians
    with torch.no_grad():
        out = t._raster(
            g.means, g.log_scales, g.quats, g.opacity_logits,
            t.color.colors(g, view.camera.center), view.camera, t.background,
        )  # fmt: skip
        both = t.consistency.extra_loss(1, g, out, view)
        assert both is not None
        singles = []
        for j in t.consistency.partners[view.index]:
            t.consistency.partners[view.index] = [j]
            one = t.consistency.extra_loss(1, g, out, view)
            assert one is not None and float(one) > 0
            singles.append(float(one))
    # the same float32 arithmetic summed in another order: a few roundoffs of the terms
    assert float(both) == pytest.approx(sum(singles) / 2, rel=1e-6)


def test_consistency_with_a_single_view_has_no_partner() -> None:
    scene, depths = make_scene(seed=2, n_train=1)
    t = Trainer(scene, small(consistency_weight=1.0, iterations=10), depths)
    assert t.consistency is not None and t.consistency.partners == [[]]
    t.run()
    assert _finite(t)


def test_consistency_start_is_compressed_with_the_schedule() -> None:
    cfg = preset("llff", 1500, consistency_weight=0.1, consistency_start=3000).with_iterations(150)
    assert cfg.iterations == 150 and cfg.consistency.start == 300  # 3000 at 1500 iterations


# -- near-plane pruning ------------------------------------------------------------------------


def _occluder_rows(t: Trainer, cam: Any) -> dict[str, torch.Tensor]:
    """One opaque Gaussian 0.3 near bounds in front of a camera (inside the default prune
    radius of 0.5 near, beyond the raster near plane of 0.2 near): it covers that view."""
    rows = {k: v[:1].detach().clone() for k, v in t.gaussians.params.items()}
    forward = cam.camera_to_world[:3, 2].float()
    rows["means"] = (cam.center.float() + 0.3 * t.scene.near * forward).reshape(1, 3)
    rows["log_scales"] = torch.full((1, 3), math.log(0.2 * t.scene.near))
    rows["opacity_logits"] = torch.full_like(rows["opacity_logits"], 8.0)
    return rows


@pytest.mark.parametrize("seed", [0, 1])
def test_near_prune_deletes_gaussians_near_the_cameras_in_training(seed: int) -> None:
    scene, priors = make_scene(seed=seed)
    t = Trainer(scene, small(seed=seed, near_prune=True, near_prune_start=0), priors)
    assert t.near_prune is not None
    for v in scene.train:
        t.gaussians.append(_occluder_rows(t, v.camera), t.optimizer)
    res = t.run()
    assert res.metrics["near_pruned"] >= len(scene.train)
    centres = torch.stack([v.camera.center.double() for v in scene.train])
    nearest = torch.cdist(t.gaussians.means.detach().double(), centres).min().item()
    assert nearest >= t.near_prune.radius
    assert _finite(t) and math.isfinite(res.metrics["psnr"])


def test_near_prune_evaluation_ignores_what_sits_at_a_held_out_camera() -> None:
    scene, priors = make_scene(seed=3)
    scores = {}
    for on in (False, True):
        t = Trainer(scene, small(near_prune=on, iterations=10), priors)
        t.run()
        clean = t.evaluate()["psnr"]
        for v in scene.test:
            t.gaussians.append(_occluder_rows(t, v.camera))
        scores[on] = (clean, t.evaluate()["psnr"])
    assert scores[True][0] == scores[True][1]  # the occluders are left out of the renders
    assert scores[False][1] < scores[False][0] - 1.0  # ... and without pruning they cover them


def test_forward_facing_cameras_get_the_dense_init_and_the_coarse_hard_pass(tmp_path: Path) -> None:
    scene, depths = make_scene(seed=0, width=40, height=30)  # train views within 29 degrees
    metric = _true_depth_priors(scene, depths)
    cfg = small(init="auto", dense_init_points=150)
    t = Trainer(scene, cfg, depths, tmp_path, init_depth=metric)
    assert t.init_note == "dense: 150 points" and len(t.gaussians) == 150
    assert t.depth is not None and t.depth.hard_level.downscale == 2  # the preset's rule too


def test_an_orbit_gets_the_random_box_and_the_full_resolution_hard_pass(tmp_path: Path) -> None:
    scene, depths = make_scene(seed=0, width=40, height=30)
    orbit = [
        dataclasses.replace(v, camera=look_at_camera(angle, v.camera))
        for v, angle in zip(scene.train, (-1.4, 0.0, 1.4), strict=True)
    ]  # three views 80 degrees apart around the origin
    scene = dataclasses.replace(scene, train=orbit)
    t = Trainer(scene, small(init="auto", dense_init_points=150), depths, tmp_path)
    assert t.init_note is not None and t.init_note.startswith(
        "random: training cameras inward-looking"
    )
    assert len(t.gaussians) == 200  # the random box's count, not the dense one
    assert t.depth is not None and t.depth.hard_level is t.depth.full  # full resolution


def look_at_camera(angle: float, like: Camera) -> Camera:
    """``like``'s intrinsics at 4 units from the origin, ``angle`` radians around it."""
    eye = torch.tensor([4.0 * math.sin(angle), 0.0, -4.0 * math.cos(angle)])
    return Camera(look_at(eye, torch.zeros(3)), like.fx, like.fy, like.cx, like.cy,
                  like.width, like.height)  # fmt: skip


def test_consistency_last_partner_depth_reuses_the_partners_own_render() -> None:
    """``partner_depth='last'``: a partner trained before is not rendered again; its seen depth
    is the one of its own photometric render. A partner not trained yet is rendered."""
    scene, depths = make_scene(seed=4, n_train=3)
    cfg = small(
        consistency_weight=0.5, consistency_start=0, **{"consistency.partner_depth": "last"}
    )
    t = Trainer(scene, cfg, depths)
    c = t.consistency
    assert c is not None
    calls = []
    render = c.raster

    def counted(*args: Any, **kwargs: Any) -> Any:
        calls.append(1)
        return render(*args, **kwargs)

    c.raster = counted
    g = t.gaussians
    views = {v.index: v for v in (t._next_view() for _ in range(3))}

    def photometric(index: int) -> Any:
        cam = views[index].camera
        return t._raster(
            g.means, g.log_scales, g.quats, g.opacity_logits,
            t.color.colors(g, cam.center), cam, t.background,
        )  # fmt: skip

    with torch.no_grad():
        first = 0
        partner = c.partners[first][0]
        out_first = photometric(first)
        assert c.extra_loss(1, g, out_first, views[first]) is not None
        assert len(calls) == 1  # the partner was not trained yet: rendered
        out_partner = photometric(partner)
        assert c.extra_loss(1, g, out_partner, views[partner]) is not None
        kept = c.last_depth[partner]
        assert kept is not None and torch.equal(
            kept, seen_depth(out_partner.depth, out_partner.alpha)
        )
        before = len(calls)
        again = c.extra_loss(1, g, out_first, views[first])
        assert len(calls) == before  # the partner's own render was reused
        expected = 0.5 * warp_consistency_loss(
            t.images[first], t.images[partner], out_first.depth, views[first].camera,
            views[partner].camera, alpha=out_first.alpha, source_depth=kept,
        )  # fmt: skip
        assert again is not None and torch.equal(again, expected)
