"""Results do not depend on the scene's unit: the millimetre copy of an upload trains like the
metre copy (issue #11: the initial Gaussian count was 50 per scene unit)."""

from __future__ import annotations

from pathlib import Path

import pytest

from sparsesplat.engine.datasets import load_scene
from sparsesplat.engine.train import Trainer
from tests.cli.scenes import write_object_scene
from tests.engine.datasets.synthetic import smoke_preset


def _config():  # type: ignore[no-untyped-def]
    """The default preset's automatic initial count, compressed to smoke scale."""
    return smoke_preset("default", 30, seed=3, checkpoint_interval_s=0)


def test_millimetre_copy_trains_like_the_metre_copy(tmp_path: Path) -> None:
    metre = load_scene(write_object_scene(tmp_path / "m", size=24, alpha=False))
    milli = load_scene(write_object_scene(tmp_path / "mm", size=24, alpha=False, scale=1000.0))
    assert milli.near == pytest.approx(1000 * metre.near, rel=1e-4)
    runs = {}
    for name, scene in (("m", metre), ("mm", milli)):
        trainer = Trainer(scene, _config())
        start = len(trainer.gaussians)
        result = trainer.run()
        assert result.metrics["psnr"] > result.records[0]["psnr"] + 1.0, name  # it trains
        runs[name] = (start, result.metrics["psnr"])
    (n_m, psnr_m), (n_mm, psnr_mm) = runs["m"], runs["mm"]
    assert n_m == n_mm, f"initial Gaussians differ by unit: {runs}"
    assert 1000 <= n_m < 5000, runs
    assert abs(psnr_m - psnr_mm) < 0.5, f"PSNR depends on the unit: {runs}"


def test_checkpoints_from_before_the_unit_free_count_still_load() -> None:
    from sparsesplat.engine.train import TrainConfig
    from sparsesplat.engine.train.config.overrides import config_from_dict
    from tests.engine.train.config.test_config import legacy_flat_dict

    old = {**legacy_flat_dict(_config()), "init_points_per_unit": 50.0}
    old.pop("init_points_density")
    assert config_from_dict(old).init.points_density == TrainConfig().init.points_density
