"""Opacity decay (``densify.opacity_decay``): every opacity scaled after each step of the
densification window, nothing after it."""

from __future__ import annotations

import math

import pytest
import torch

from sparsesplat.engine.synthetic import make_scene
from sparsesplat.engine.train import Trainer
from sparsesplat.engine.train.config import ConfigError
from sparsesplat.engine.train.config.presets import PRESET_ITERATIONS, preset

from .test_trainer import small


def _opacity_after_first_step(seed: int, **overrides: object) -> torch.Tensor:
    """Opacities (float64) after iteration 1 of a no-depth smoke run."""
    scene, priors = make_scene(seed=seed)
    trainer = Trainer(scene, small(seed=seed, **{"depth.prior": "none"}, **overrides), priors)
    trainer.iteration = 1
    trainer._step()
    assert bool(torch.isfinite(trainer.gaussians.opacity_logits).all())
    return trainer.gaussians.opacity.detach().double()


@pytest.mark.parametrize("seed", [0, 1])
def test_decay_scales_every_opacity_inside_the_densification_window(seed: int) -> None:
    """Same seed, same step: with the decay every opacity is the plain run's times the
    factor (to the float32 rounding of a logit near 0: relative 1e-5); at or past
    densify_until the two runs are bit-identical."""
    factor = 0.9
    decay = {"densify.opacity_decay": factor}
    plain = _opacity_after_first_step(seed, densify_until=3)
    decayed = _opacity_after_first_step(seed, densify_until=3, **decay)
    assert float((decayed / plain - factor).abs().max()) < 1e-5
    outside = _opacity_after_first_step(seed, densify_until=1, **decay)
    assert torch.equal(outside, _opacity_after_first_step(seed, densify_until=1))


def test_decay_keeps_extreme_logits_finite() -> None:
    """Logits of +-100 (opacity 1 and 0 in float32) decay to finite values with the right
    opacity ratio."""
    scene, priors = make_scene(seed=0)
    t = Trainer(scene, small(**{"depth.prior": "none"}), priors)
    with torch.no_grad():
        t.gaussians.opacity_logits[:2] = torch.tensor([100.0, -100.0])
    t.gaussians.decay_opacity(0.995)
    x = t.gaussians.opacity_logits[:2].double()
    assert bool(torch.isfinite(x).all())
    assert math.isclose(float(torch.sigmoid(x[0])), 0.995, rel_tol=1e-6)
    assert math.isclose(float(x[1]), -100.0 + math.log(0.995), rel_tol=1e-6)


@pytest.mark.parametrize("bad", [0.0, -0.5, 1.5, float("nan")])
def test_decay_factor_is_checked(bad: float) -> None:
    with pytest.raises(ConfigError, match="opacity_decay"):
        small(**{"densify.opacity_decay": bad})


def test_which_presets_decay_by_default() -> None:
    """The Blender recipe (and ``object``, its unit-free twin) decays opacity by 0.995, the
    DTU preset by 0.998, the LLFF-style base recipe not at all (its orbit recipe does:
    test_layout_recipe.py; docs/experiments/2026-11-27-blender-opacity-decay.md). The window
    is the whole run in these presets: densification runs to their end."""
    for name, factor in (("blender", 0.995), ("object", 0.995), ("dtu", 0.998)):
        config = preset(name)
        assert config.densify.opacity_decay == factor, name
        assert config.densify.until == config.iterations == PRESET_ITERATIONS[name], name
    for name in ("llff", "default"):
        assert preset(name).densify.opacity_decay == 1.0, name
