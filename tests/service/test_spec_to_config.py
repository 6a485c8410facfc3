"""A job's spec becomes the engine's training config: each switch a user sets reaches its
field, and a switch left out keeps the preset's value."""

from __future__ import annotations

import pytest
from pydantic import ValidationError

from sparsesplat.api.jobs import JobSpec
from sparsesplat.engine.train import preset
from sparsesplat.worker.job_runner import build_config


def test_unset_switches_keep_the_presets_values() -> None:
    config, reason = build_config(JobSpec(preset="dtu"), scene=None)
    assert reason is None
    want = preset("dtu")
    fields = ("init", "dropout", "dtu_background", "consistency_weight", "near_prune")
    fields += ("depth_min_agreement",)
    for field in (*fields, "color_model"):
        assert getattr(config, field) == getattr(want, field), field


def test_each_part_switch_reaches_the_training_config() -> None:
    spec = JobSpec(
        preset="llff",
        init="dense",
        dropout=True,
        dtu_background=True,
        consistency_weight=0.1,
        near_prune=True,
        depth_min_agreement=0.3,
        iterations=1500,
    )
    config, _ = build_config(spec, scene=None)
    assert config.init == "dense"
    assert config.dropout is True
    assert config.dtu_background is True
    assert config.consistency_weight == pytest.approx(0.1)
    assert config.near_prune is True
    assert config.depth_min_agreement == pytest.approx(0.3)
    assert config.iterations == 1500


@pytest.mark.parametrize(
    "bad",
    [
        {"init": "mvs"},
        {"consistency_weight": -1.0},
        {"dropout": "often"},
        {"near_prune": "x"},
        {"depth_min_agreement": 2},
    ],
)
def test_bad_switch_values_are_rejected_with_the_field_named(bad: dict) -> None:
    with pytest.raises(ValidationError) as info:
        JobSpec(**bad)
    assert next(iter(bad)) in str(info.value)
