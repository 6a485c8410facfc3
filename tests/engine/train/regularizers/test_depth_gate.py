"""The depth-prior agreement gate: views whose prior ranks depth against the scene's own
plane-sweep geometry lose their depth passes; a gate that keeps no view builds no depth part.

The synthetic scene's true depth agrees with its plane sweep (Spearman 0.42-0.71 at the sizes
used, fixed scene seeds) and the negated depth disagrees by the same amount, so a 0.3 threshold
sits well inside both margins."""

from __future__ import annotations

import math
from typing import Any

import pytest
import torch

from sparsesplat.engine.priors.base import PriorDepth
from sparsesplat.engine.synthetic import make_scene
from sparsesplat.engine.train import Trainer
from sparsesplat.engine.train.config import ConfigError
from sparsesplat.engine.train.regularizers.depth_gate import agreeing_views, as_prior
from tests.engine.train.loop.test_trainer_parts import small as parts_config


def small(**overrides: Any):  # type: ignore[no-untyped-def]
    """The trainer-parts smoke config, 20 iterations."""
    base: dict[str, Any] = dict(
        iterations=20, lr_means_steps=20, soft_depth_start=5, densify_until=15,
        depth_smooth_start=10,
    )  # fmt: skip
    return parts_config(**(base | overrides))


@pytest.mark.parametrize("scene_seed", [0, 1])
def test_agreeing_and_reversed_priors_are_told_apart(scene_seed: int) -> None:
    scene, depths = make_scene(seed=scene_seed, width=64, height=48)
    mixed = [depths[0], -depths[1], depths[2]]
    keep, rhos = agreeing_views(scene, mixed, 0.3)
    assert keep == {0, 2}
    assert rhos[0] > 0.3 and rhos[2] > 0.3 and rhos[1] < -0.3
    keep, _ = agreeing_views(scene, [-d for d in depths], 0.3)
    assert keep == set()


def test_a_view_that_cannot_be_judged_keeps_its_prior() -> None:
    scene, depths = make_scene(seed=0)
    flat = torch.full_like(depths[0], 2.0)  # constant: no ranking to compare
    keep, rhos = agreeing_views(scene, [flat, depths[1], depths[2]], 0.3)
    assert math.isnan(rhos[0]) and 0 in keep


def test_the_plane_sweep_prior_is_its_own_reference() -> None:
    scene, depths = make_scene(seed=0)
    sweep = [PriorDepth(d, torch.ones_like(d), True, kind="plane_sweep") for d in depths]
    assert agreeing_views(scene, sweep, 0.99) == ({0, 1, 2}, [1.0, 1.0, 1.0])
    assert as_prior(sweep[0]) is sweep[0]


def test_skipped_views_get_no_depth_pass(monkeypatch: pytest.MonkeyPatch) -> None:
    scene, depths = make_scene(seed=0, width=64, height=48)
    t = Trainer(scene, small(depth_min_agreement=0.3), [depths[0], -depths[1], depths[2]])
    assert t.depth is not None and t.depth.views == {0, 2}
    seen: set[int] = set()
    real = t.depth.depth_loss

    def spy(depth: torch.Tensor, index: int, *args: Any, **kwargs: Any) -> torch.Tensor:
        seen.add(index)
        return real(depth, index, *args, **kwargs)

    monkeypatch.setattr(t.depth, "depth_loss", spy)
    res = t.run()
    assert seen == {0, 2}
    assert res.metrics["depth_views"] == [0, 2] and len(res.metrics["depth_agreement"]) == 3


def test_a_gate_that_keeps_no_view_is_the_no_depth_run() -> None:
    scene, depths = make_scene(seed=1, width=64, height=48)
    gated = Trainer(scene, small(depth_min_agreement=0.3), [-d for d in depths])
    assert gated.depth is None
    gated.run()
    plain = Trainer(scene, small(depth_prior="none"), None)
    plain.run()
    # Same code path and the same random draws: identical to the bit.
    for name, value in plain.gaussians.params.items():
        assert torch.equal(gated.gaussians.params[name], value), name


@pytest.mark.parametrize("bad", [1.5, -2.0])
def test_thresholds_outside_the_correlation_range_are_config_errors(bad: float) -> None:
    with pytest.raises(ConfigError, match=r"depth\.min_agreement"):
        small(depth_min_agreement=bad)
