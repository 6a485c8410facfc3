"""``make bench-iteration --trained SCENE CHECKPOINT``: iterations continuing a real run."""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any

import pytest
import torch

from benchmarks.iteration import measure, measure_trained
from sparsesplat.engine.datasets import load_scene
from sparsesplat.engine.model.checkpoint import load_checkpoint
from sparsesplat.engine.train import Trainer, preset
from tests.cli.scenes import write_object_scene


def test_trained_row_continues_the_checkpoint_at_its_gaussian_count(tmp_path: Path) -> None:
    """The trained row times the checkpoint's model (its Gaussian count, kept fixed: the run
    densified, the bench does not) and splits the time into the trainer's stages."""
    scene_dir = write_object_scene(tmp_path / "scene", count=6, test=2, size=32, alpha=False)
    scene = load_scene(scene_dir)
    overrides: dict[str, Any] = {
        "record.export": False, "record.eval_lpips": False, "record.eval_interval_s": 0,
        "depth.prior": "none", "densify.interval": 5, "densify.start": 5, "densify.until": 40,
        "densify.grad_threshold": 1e-9,
    }  # fmt: skip
    config = preset("object", iterations=40, **overrides)
    result = Trainer(scene, config, None, tmp_path / "run").run()
    checkpoint = Path(result.artifacts["checkpoint"])
    saved = load_checkpoint(checkpoint)
    n_saved = saved["gaussians"]["means"].shape[0]
    assert n_saved > config.init.points  # the run densified

    # A threshold every Gaussian passes: were densification still on, the count would grow.
    eager = {"depth.prior": "none", "densify.grad_threshold": 1e-9, "densify.interval": 1}
    row = measure_trained(str(scene_dir), str(checkpoint), 3, eager | {"densify.start": 0})
    assert row["gaussians"] == n_saved
    stages = {k: v for k, v in row.items() if k not in ("gaussians", "total_s")}
    assert {"photo_render", "photo_backward", "optimizer"} <= set(stages)
    assert all(v >= 0 for v in stages.values())
    # The stages are consecutive slices of each timed iteration.
    assert sum(stages.values()) <= row["total_s"] * 1.05
    assert torch.isfinite(torch.tensor(row["total_s"]))


def _check_box_row(row: dict[str, float], n: int) -> None:
    assert row["gaussians"] == n  # densification is off: the count stays the box's
    assert math.isfinite(row["total_s"]) and row["total_s"] > 0
    assert {"hard_depth", "soft_depth", "photo_render", "optimizer"} <= set(row)


def test_the_random_box_row_times_every_pass() -> None:
    _check_box_row(measure(1500, 1, width=96, height=72), 1500)


@pytest.mark.cuda
@pytest.mark.skipif(not torch.cuda.is_available(), reason="no CUDA GPU available")
def test_the_random_box_row_on_a_gpu() -> None:
    pytest.importorskip("gsplat")
    _check_box_row(measure(1500, 2, device="cuda"), 1500)
