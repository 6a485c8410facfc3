"""A trained model as the render worker serves it: the exact neural mode against the trainer's
own evaluation render and a float64 reference, the baked mode against the trainer's export."""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any

import pytest
import torch

from sparsesplat.engine.color.models import NeuralColor
from sparsesplat.engine.color.neural import _OUT_SCALE, NeuralColorField
from sparsesplat.engine.color.sh import sh_basis
from sparsesplat.engine.color.view_colors import BakedViewColors, NeuralViewColors
from sparsesplat.engine.export.ply import read_ply
from sparsesplat.engine.export.sh_eval import eval_sh
from sparsesplat.engine.model import CheckpointError, TrainedModel, load_model
from sparsesplat.engine.model.render import render_view, view_colors
from sparsesplat.engine.raster import rasterize
from sparsesplat.engine.synthetic import make_scene
from sparsesplat.engine.train import Trainer
from tests.engine.train.loop.test_trainer import small

UNIT_ROUNDOFF = 2.0**-24


SERVING_SCHEDULE: dict[str, Any] = {
    "iterations": 20, "export": True, "lr_means_steps": 20, "soft_depth_start": 10,
    "densify_from": 5, "densify_until": 15, "densify_interval": 5, "depth_smooth_start": 10,
}  # fmt: skip
"""test_trainer's smoke recipe at half its length, with the exports the serving tests read."""


def _small(**overrides: Any):  # type: ignore[no-untyped-def]
    return small(**{**SERVING_SCHEDULE, **overrides})


@pytest.fixture(scope="module")
def trained(tmp_path_factory: pytest.TempPathFactory) -> tuple[Any, Path, dict[str, Any]]:
    """A 20-iteration neural-colour run at 32x24 with its exports: (scene, run folder, metrics)."""
    out = tmp_path_factory.mktemp("serving")
    scene, priors = make_scene(seed=0)
    result = Trainer(scene, _small(), priors, out).run()
    return scene, out, result.metrics


def _head_bound(field: NeuralColorField, geo: torch.Tensor, dirs: torch.Tensor) -> torch.Tensor:
    """Float64 colours of the colour head from float32 geometry features, and a bound on the
    float32 error of either evaluation order: products of length n err by at most
    gamma_n = n u / (1 - n u) of the sum of absolute terms (the first layer's 80 terms, then the
    output layer's 64 over the first layer's bound); the scaled sigmoid is at most
    _OUT_SCALE / 4-Lipschitz, and it adds a few roundings of its own."""
    w = field.color_mlp[0].weight.detach().double()
    w2 = field.color_mlp[2].weight.detach().double()
    code = torch.cat([sh_basis(dirs.double(), 3), geo.double()], dim=1)
    pre = code @ w.T
    gamma = lambda n: n * UNIT_ROUNDOFF / (1 - n * UNIT_ROUNDOFF)  # noqa: E731
    # The 16-value code itself is float32: its rounding (a few ulp of values <= 1.1) enters too.
    pre_err = gamma(80) * (code.abs() @ w.abs().T) + 8 * UNIT_ROUNDOFF * (w[:, :16].abs().sum(1))
    h = torch.relu(pre)
    out = h @ w2.T
    out_err = gamma(64) * (h.abs() @ w2.abs().T) + pre_err @ w2.abs().T
    rgb = torch.sigmoid(out) * _OUT_SCALE - 0.001
    return rgb, out_err * _OUT_SCALE / 4 + 4 * UNIT_ROUNDOFF


def test_neural_view_colours_match_a_float64_reference(trained: Any) -> None:
    scene, run, _ = trained
    model = load_model(run)
    assert isinstance(model.color, NeuralColor)
    field, means = model.color.field, model.gaussians.means.detach()
    colours = NeuralViewColors(field, means)
    geo = field.geo_features(means)
    for view in scene.train + scene.test:
        centre = view.camera.center.float()
        dirs = torch.nn.functional.normalize(means - centre, dim=-1)
        want, bound = _head_bound(field, geo, dirs)
        for got in (colours(centre), field.colors_from_features(geo, dirs)):
            err = (got.double() - want).abs()
            assert bool((err <= bound).all()), f"worst excess {float((err - bound).max()):.3g}"


def test_exact_mode_equals_the_trainers_evaluation_render(trained: Any) -> None:
    scene, run, _ = trained
    model = load_model(run)
    raster = lambda *a: rasterize(  # noqa: E731
        *a,
        near=model.raster_near,
        eps2d=model.raster.eps2d,
        backend=model.raster.backend,
    )
    geo = model.color.geo_features(model.gaussians)
    for view in scene.test:
        served = model.render(view.camera, mode="neural").image
        colours = view_colors(model.color, model.gaussians, geo)
        trainer = render_view(model.gaussians, colours, view.camera, model.background, raster).image
        # The colours agree to float32 rounding (above); blended over a few dozen splats the
        # images stay far inside one 8-bit step.
        assert float((served - trainer).abs().max()) < 1e-5


def test_baked_mode_is_the_export_and_scores_the_trainers_baking_psnr(trained: Any) -> None:
    scene, run, metrics = trained
    model = load_model(run)
    ply = read_ply(run / "model.ply")
    assert torch.equal(ply["means"], model.gaussians.means.detach())
    model.use_baked_sh(ply["sh"])
    g = model.gaussians
    psnrs = []
    for view in scene.train:  # the trainer scores its bake on the training cameras
        baked = model.render(view.camera, mode="baked").image
        colours = eval_sh(ply["sh"], g.means.detach() - view.camera.center.float())
        with torch.no_grad():
            want = rasterize(
                g.means, g.log_scales, g.quats, g.opacity_logits, colours, view.camera,
                model.background, near=model.raster_near, eps2d=model.raster.eps2d,
            ).image  # fmt: skip
        assert torch.equal(baked, want)
        neural = model.render(view.camera, mode="neural").image
        mse = float(((baked.clamp(0, 1) - neural.clamp(0, 1)).double() ** 2).mean())
        psnrs.append(math.inf if mse == 0 else -10 * math.log10(mse))
    assert sum(psnrs) / len(psnrs) == pytest.approx(metrics["sh_baking_psnr"], abs=0.01)


def test_a_model_without_export_bakes_its_own_sh(trained: Any) -> None:
    scene, run, _ = trained
    model = load_model(run)
    sh = model.baked_sh()
    assert sh.shape == (len(model), 16, 3)
    colours = BakedViewColors(sh, model.gaussians.means.detach())
    centre = scene.test[0].camera.center.float()
    want = eval_sh(sh, model.gaussians.means.detach() - centre)
    assert torch.allclose(colours(centre), want, atol=1e-6)
    image = model.render(scene.test[0].camera, mode="baked").image
    assert image.shape == (3, 24, 32) and bool(torch.isfinite(image).all())


def test_sh_colour_models_render_the_same_in_both_modes(tmp_path: Path) -> None:
    scene, priors = make_scene(seed=1)
    Trainer(scene, _small(color_model="sh", export=False), priors, tmp_path).run()
    model = load_model(tmp_path)
    cam = scene.test[0].camera
    assert torch.equal(
        model.render(cam, mode="neural").image, model.render(cam, mode="baked").image
    )


def test_bad_mode_and_bad_sh_are_refused(trained: Any) -> None:
    scene, run, _ = trained
    model: TrainedModel = load_model(run)
    with pytest.raises(CheckpointError, match="render mode"):
        model.render(scene.test[0].camera, mode="fast")  # type: ignore[arg-type]
    with pytest.raises(CheckpointError, match="do not fit"):
        model.use_baked_sh(torch.zeros(len(model) + 1, 16, 3))
    with pytest.raises(ValueError, match="do not fit"):
        BakedViewColors(torch.zeros(len(model), 5, 3), model.gaussians.means)
