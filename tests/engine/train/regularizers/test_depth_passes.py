"""The hard depth pass does what the method says: against an exact prior it moves the centres
so that the rendered depth follows the prior (only the centres move)."""

from __future__ import annotations

import pytest
import torch

from sparsesplat.engine.synthetic import make_scene
from sparsesplat.engine.train import Trainer
from sparsesplat.engine.train.loop.parts import AuxiliaryStep, StageTimer
from tests.engine.train.loop.test_trainer_parts import small


def _pearson(a: torch.Tensor, b: torch.Tensor) -> float:
    a, b = a.double().flatten(), b.double().flatten()
    a, b = a - a.mean(), b - b.mean()
    return float((a * b).sum() / (a.norm() * b.norm()))


def _hard_depth_agreement(t: Trainer, priors: list[torch.Tensor]) -> float:
    """Mean over training views of the correlation between the hard-pass depth render and the
    prior (the quantity the global term of the depth loss compares)."""
    assert t.depth is not None
    g, scores = t.gaussians, []
    with torch.no_grad():
        for i, camera in enumerate(t.cameras):
            hard = torch.full((len(g),), t.depth.hard_logit)
            empty = g.means.new_zeros(len(g), 0)
            out = t._raster(g.means, g.log_scales, g.quats, hard, empty, camera, None)
            scores.append(_pearson(out.depth, priors[i]))
    return sum(scores) / len(scores)


@pytest.mark.parametrize(("seed", "downscale"), [(0, 1), (1, 1), (2, 1), (0, 2), (1, 2), (2, 2)])
def test_hard_depth_pass_pulls_rendered_depth_to_an_exact_prior(seed: int, downscale: int) -> None:
    """At the training resolution and at half of it (``depth.hard_downscale=2``), the judge
    being the full-resolution agreement either way."""
    scene, depths = make_scene(seed=seed, width=40, height=30)
    cfg = small(soft_depth=False, hard_depth_start=0, **{"depth.hard_downscale": downscale})
    t = Trainer(scene, cfg, depths)
    assert t.depth is not None
    before = {k: v.detach().clone() for k, v in t.gaussians.params.items()}
    start = _hard_depth_agreement(t, depths)
    timer = StageTimer(False)
    for it in range(1, 91):  # only the depth pass: no photometric step in between
        view = t._next_view()
        step = AuxiliaryStep(it, t.gaussians, t.optimizer, view, t.extent, t.guard, timer)
        t.depth.step_pre_photometric(step)
    end = _hard_depth_agreement(t, depths)
    assert end > start + 0.5, (start, end)  # measured: +0.79 to +1.07 (seeds 0-2)
    moved = {k for k, v in t.gaussians.params.items() if not torch.equal(v.detach(), before[k])}
    assert moved == {"means"}


def _iterate(t: Trainer, count: int) -> None:
    for _ in range(count):
        t.iteration += 1
        t._step()


def _adam_steps(t: Trainer) -> int:
    """Adam steps taken on the centres so far."""
    return int(t.optimizer.state[t.gaussians.means]["step"])


@pytest.mark.parametrize("mode, steps_per_iteration", [("separate", 2), ("joint", 1)])
def test_auxiliary_step_joint_leaves_the_depth_gradient_for_the_photometric_step(
    mode: str, steps_per_iteration: int
) -> None:
    """'separate' (the reference code): the hard pass takes an Adam step of its own, so the
    centres get two per iteration; 'joint' (the paper's summed objective): the pass only adds
    its gradient, nothing moves until the one photometric step."""
    scene, depths = make_scene(seed=0, width=40, height=30)
    cfg = small(soft_depth=False, hard_depth_start=0, densify_from=10_000, auxiliary_step=mode)
    t = Trainer(scene, cfg, depths)
    assert t.depth is not None
    _iterate(t, 3)  # Adam state exists from here on
    before = {k: v.detach().clone() for k, v in t.gaussians.params.items()}
    steps = _adam_steps(t)
    view = t._next_view()
    t.depth.step_pre_photometric(
        AuxiliaryStep(
            t.iteration + 1, t.gaussians, t.optimizer, view, t.extent, t.guard, StageTimer(False)
        )
    )
    grad = t.gaussians.means.grad
    moved = {k for k, v in t.gaussians.params.items() if not torch.equal(v.detach(), before[k])}
    if mode == "joint":
        assert moved == set() and _adam_steps(t) == steps
        assert grad is not None and float(grad.abs().max()) > 0
        assert all(p.grad is None for k, p in t.gaussians.params.items() if k != "means")
    else:
        assert moved == {"means"} and _adam_steps(t) == steps + 1 and grad is None
    t.optimizer.zero_grad(set_to_none=True)
    start = _adam_steps(t)
    _iterate(t, 3)
    assert _adam_steps(t) - start == 3 * steps_per_iteration
