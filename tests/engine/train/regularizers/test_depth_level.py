"""The hard pass's coarse depth level (``depth.hard_downscale``): the prior averaged to the
render's size, the patch range scaled with it, the background mask carried over."""

from __future__ import annotations

import math

import pytest
import torch

from sparsesplat.engine.camera import Camera
from sparsesplat.engine.synthetic import look_at, make_cameras
from sparsesplat.engine.train.config import ConfigError, DepthConfig
from sparsesplat.engine.train.regularizers.depth_regularizer import (
    DepthLevel,
    _coarse_mask,
    downscale_depth,
    hard_downscale,
)


def _block_means(x: torch.Tensor, f: int) -> torch.Tensor:
    """float64 reference: the mean of each f x f block (sizes divisible by f)."""
    h, w = x.shape
    return x.double().reshape(h // f, f, w // f, f).mean(dim=(1, 3))


@pytest.mark.parametrize("f", [2, 3, 4])
def test_downscaled_prior_is_the_mean_of_each_block(f: int) -> None:
    g = torch.Generator().manual_seed(f)
    prior = torch.rand(12 * 5, 12 * 7, generator=g) * 50 + 1
    got = downscale_depth(prior, (prior.shape[0] // f, prior.shape[1] // f))
    ref = _block_means(prior, f)
    # A mean of f^2 float32 values in [1, 51]: each rounding at most 2^-24 relative, f^2 adds.
    bound = f * f * 51 * 2.0**-24 * 2
    assert got.shape == ref.shape
    assert float((got.double() - ref).abs().max()) <= bound


def test_level_matches_the_scaled_camera_and_scales_the_patches() -> None:
    prior = torch.rand(378, 504, generator=torch.Generator().manual_seed(0)) + 1
    camera = Camera(torch.eye(4), 400.0, 400.0, 252.0, 189.0, 504, 378)
    for f, patches in ((1, (5, 17)), (2, (3, 9)), (3, (2, 6))):
        level = DepthLevel.build([prior], f, (5, 17), smooth=True)
        scaled = camera.scaled(1 / f)
        assert level.priors[0].shape == (scaled.height, scaled.width)
        assert level.patch_range == patches
        assert level.targets[0].smooth_weights is not None
        guide = level.guides[0]
        assert float(guide.min()) == 0.0 and abs(float(guide.max()) - 257.0) < 1e-3


def test_odd_sizes_round_as_the_camera_does() -> None:
    prior = torch.rand(31, 45, generator=torch.Generator().manual_seed(1))
    level = DepthLevel.build([prior], 2, (5, 17), smooth=False)
    scaled = Camera(torch.eye(4), 30.0, 30.0, 22.5, 15.5, 45, 31).scaled(0.5)
    assert level.priors[0].shape == (scaled.height, scaled.width)
    assert level.targets[0].smooth_weights is None


def test_coarse_mask_is_the_majority_of_each_block() -> None:
    mask = torch.zeros(8, 8, dtype=torch.bool)
    mask[:4, :4] = True  # one whole 2x2 block region of the coarse grid
    mask[4, 4] = True  # a lone fine pixel: a minority of its block
    level = DepthLevel.build([torch.ones(8, 8)], 2, (5, 17), smooth=False)
    coarse = _coarse_mask(mask, level)
    expected = torch.zeros(4, 4, dtype=torch.bool)
    expected[:2, :2] = True
    assert torch.equal(coarse, expected)


def test_hard_downscale_must_be_positive() -> None:
    with pytest.raises(ConfigError, match=r"depth\.hard_downscale"):
        DepthConfig(hard_downscale=0).validate()


def _orbit(angles: tuple[float, ...]) -> list[Camera]:
    cams = []
    for a in angles:
        eye = torch.tensor([4.0 * math.sin(a), 0.0, -4.0 * math.cos(a)])
        cams.append(Camera(look_at(eye, torch.zeros(3)), 30.0, 30.0, 20.0, 15.0, 40, 30))
    return cams


def test_unset_hard_downscale_follows_the_camera_layout() -> None:
    forward = make_cameras(3, 40, 30)  # an arc within 29 degrees of the mean view
    orbit = _orbit((-1.4, 0.0, 1.4))  # 80 degrees apart, converging on the origin
    unset = DepthConfig(hard_downscale=None)
    assert hard_downscale(unset, forward) == 2
    assert hard_downscale(unset, orbit) == 1
    for n in (1, 3):  # a set value is kept whatever the layout
        assert hard_downscale(DepthConfig(hard_downscale=n), orbit) == n
        assert hard_downscale(DepthConfig(hard_downscale=n), forward) == n
