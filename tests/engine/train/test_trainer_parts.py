"""The optional training parts wired into the loop (dropout, dense init, DTU background,
warp consistency): switched off they are not built; switched on they do what their module
says at trainer level, on tiny synthetic scenes."""

from __future__ import annotations

import math
from typing import Any

import pytest
import torch

from sparsesplat.engine.raster import RasterOutput
from sparsesplat.engine.synthetic import make_scene
from sparsesplat.engine.train import Trainer, preset
from sparsesplat.engine.train import trainer as trainer_module


def small(**overrides: Any):  # type: ignore[no-untyped-def]
    """The LLFF recipe at smoke scale (as in test_trainer.py)."""
    base: dict[str, Any] = dict(
        iterations=30, init_points=200, eval_interval_s=0, eval_lpips=False, export=False,
        hash_log2_size=14, lr_means_start=0, lr_means_steps=30, soft_depth_start=10,
        densify_from=5, densify_until=25, densify_interval=5, depth_smooth_start=20,
        checkpoint_interval_s=0, threads=1,
    )  # fmt: skip
    base.update(overrides)
    return preset("llff", **base)


def _finite(t: Trainer) -> bool:
    return all(bool(torch.isfinite(v).all()) for v in t.gaussians.params.values())


def test_parts_switched_off_are_not_built() -> None:
    scene, priors = make_scene(seed=0)
    t = Trainer(scene, small(), priors)
    assert t.dropout is None


# -- dropout ---------------------------------------------------------------------------------


def _spy_rasterizer(
    monkeypatch: pytest.MonkeyPatch,
) -> tuple[list[tuple[int, bool]], dict[str, Trainer]]:
    """Record (rows rendered - model size, grad enabled) of every colour render of the
    trainer (depth-only renders, with 0 feature channels, are left out)."""
    calls: list[tuple[int, bool]] = []
    holder: dict[str, Trainer] = {}
    real = trainer_module.rasterize

    def spy(means: torch.Tensor, *args: Any, **kwargs: Any) -> RasterOutput:
        t = holder.get("t")
        if t is not None and args[3].shape[-1] > 0:
            calls.append((means.shape[0] - len(t.gaussians), torch.is_grad_enabled()))
        return real(means, *args, **kwargs)

    monkeypatch.setattr(trainer_module, "rasterize", spy)
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
