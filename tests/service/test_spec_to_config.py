"""A job's spec becomes the engine's training config: each switch a user sets reaches its
field, and a switch left out keeps the preset's value."""

from __future__ import annotations

import pytest
from pydantic import ValidationError

from sparsesplat.api.jobs import JobSpec
from sparsesplat.api.settings import Settings
from sparsesplat.engine.train import preset
from sparsesplat.engine.train.config import PRESET_ITERATIONS
from sparsesplat.worker.job_runner import _with_length, build_config


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
        preset="blender",  # every part below is off in this preset
        init="dense",
        dropout=True,
        dtu_background=True,
        consistency_weight=0.1,
        near_prune=True,
        depth_min_agreement=0.3,
        iterations=1200,
    )
    off = preset("blender")
    parts = (off.init, off.dropout, off.dtu_background, off.consistency_weight, off.near_prune)
    assert (*parts, off.depth_min_agreement) == ("random", False, False, 0.0, False, None)
    config, _ = build_config(spec, scene=None)
    assert config.init == "dense"
    assert config.dropout is True
    assert config.dtu_background is True
    assert config.consistency_weight == pytest.approx(0.1)
    assert config.near_prune is True
    assert config.depth_min_agreement == pytest.approx(0.3)
    assert config.iterations == 1200


def test_run_length_is_the_presets_default_or_the_reference_schedule_compressed() -> None:
    default, _ = build_config(JobSpec(preset="llff"), scene=None)
    assert default.iterations == PRESET_ITERATIONS["llff"]
    asked, _ = build_config(JobSpec(preset="llff", iterations=3000), scene=None)
    assert (asked.iterations, asked.densify_until) == (3000, 3000)  # longer than the default
    # a time budget's length rebuilds the chosen preset (here dtu, as if chosen from the scene)
    # from its reference, with the spec's switches and the deployment's settings
    chosen, _ = build_config(JobSpec(preset="dtu", dropout=True), scene=None)
    settings = Settings(torch_threads=1)
    budget = _with_length(JobSpec(dropout=True), chosen, 1200, settings)
    assert (budget.preset, budget.iterations, budget.densify_until) == ("dtu", 1200, 1200)
    assert budget.dropout is True and budget.threads == 1


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
