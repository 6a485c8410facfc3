"""The nested training config: dotted names, the old flat names, type-hint validation, and the
stored forms of earlier versions."""

from __future__ import annotations

import dataclasses
from typing import Any

import pytest

from sparsesplat.engine.train.config import SCHEDULE_FIELDS, ConfigError, TrainConfig
from sparsesplat.engine.train.config.overrides import (
    FLAT_NAMES,
    apply_overrides,
    config_from_dict,
    field_names,
    flat_dict,
    parse_override,
)
from sparsesplat.engine.train.config.presets import PRESETS, preset

_NEW_FIELDS = {
    "time_budget_s",
    "time_limit_s",
    "consistency.partner_depth",
    "init.add_matched",
    *(f"matches.{name}" for name in ("method", "keypoints", "min_side", "max_error_px")),
    "matches.min_angle_deg",
    *(f"correspondence.{name}" for name in ("weight", "start", "until", "tolerance")),
    "correspondence.pixel_error",
    "correspondence.min_alpha",
    "correspondence.max_error",
    "poses.enabled",
    "poses.lr",
    "poses.start",
    "poses.max_rotation_deg",
    "poses.max_translation",
    *(f"binocular.{name}" for name in ("weight", "baseline", "start", "until", "every")),
    "binocular.min_alpha",
    "binocular.occlusion",
    "color.view_degree",
    "color.view_degree_interval",
    *(f"pseudo.{name}" for name in ("weight", "start", "until", "every", "t_min", "shift")),
    "pseudo.min_alpha",
    "pseudo.mode",
}
"""Fields that did not exist in the flat versions (no flat name)."""


def legacy_flat_dict(config: TrainConfig) -> dict[str, Any]:
    """``config`` as the flat ``to_dict()`` of earlier versions stored it in checkpoints."""
    dotted_to_flat = {dotted: flat for flat, dotted in FLAT_NAMES.items()}
    out = {}
    for name, value in flat_dict(config).items():
        if name in _NEW_FIELDS:
            continue
        out[dotted_to_flat.get(name, name)] = list(value) if isinstance(value, tuple) else value
    return out


def test_every_field_has_one_flat_name_and_every_flat_name_a_field() -> None:
    names = set(field_names())
    assert set(FLAT_NAMES.values()) <= names
    assert len(set(FLAT_NAMES.values())) == len(FLAT_NAMES)  # no two old names for one field
    unflat = names - set(FLAT_NAMES.values()) - _NEW_FIELDS
    # the run's own fields kept their names
    assert unflat == {"preset", "seed", "iterations", "threads", "background", "extra"}


@pytest.mark.parametrize("name", sorted(PRESETS))
def test_a_flat_stored_config_reads_back_as_the_nested_one(name: str) -> None:
    config = preset(name, iterations=333, seed=4)
    # An old checkpoint has none of the later fields: they read back as their defaults.
    defaults = TrainConfig()
    later = {
        s.split(".")[0]
        for s in _NEW_FIELDS
        if s.startswith(("matches.", "correspondence.", "binocular.", "pseudo."))
    }
    old = dataclasses.replace(
        config,
        init=dataclasses.replace(config.init, add_matched=False),
        **{section: getattr(defaults, section) for section in later},
    )
    assert config_from_dict(legacy_flat_dict(config)) == old
    assert config_from_dict(config.to_dict()) == config


def test_a_hand_written_flat_dict_of_an_old_checkpoint_loads() -> None:
    old = {"preset": "dtu", "depth_prior": "plane_sweep", "soft_depth_start": 250,
           "densify_from": 125, "dtu_background": True, "init": "dense", "dropout": True,
           "clean_iterations": [1, 25], "init_points_per_unit": 50.0}  # fmt: skip
    config = config_from_dict(old)
    assert (config.depth.prior, config.depth.soft_start, config.densify.start) == (
        "plane_sweep", 250, 125)  # fmt: skip
    assert config.dtu.enabled and config.init.method == "dense" and config.dropout.enabled
    assert config.densify.clean_iterations == (1, 25)
    # everything not in the old dict keeps its default
    assert config.depth.hard_start == TrainConfig().depth.hard_start


def test_dotted_and_flat_overrides_set_the_same_field() -> None:
    dotted = preset("llff", **{"depth.soft_start": 500, "photometric.lambda_dssim": 0.3})
    flat = preset("llff", soft_depth_start=500, lambda_dssim=0.3)
    assert dotted == flat
    assert (dotted.depth.soft_start, dotted.photometric.lambda_dssim) == (500, 0.3)


def test_overrides_are_not_compressed_but_the_preset_schedule_is() -> None:
    config = preset("llff", iterations=1500, **{"depth.soft_start": 700})
    assert config.depth.soft_start == 700 and config.densify.until == 1500


@pytest.mark.parametrize(
    ("name", "hint"),
    [("depth.soft_strat", "depth.soft_start"), ("soft_depth_strat", "depth.soft_start"),
     ("lambda_dsim", "photometric.lambda_dssim"), ("densify.untill", "densify.until")],
)  # fmt: skip
def test_unknown_names_are_named_with_a_did_you_mean(name: str, hint: str) -> None:
    with pytest.raises(ConfigError, match=rf"{name} \(did you mean {hint}\?\)"):
        preset("llff", **{name: 1})


@pytest.mark.parametrize(
    ("name", "value", "words"),
    [("depth.soft_start", "soon", "depth.soft_start must be int, got 'soon'"),
     ("depth.hard", 1, "depth.hard must be bool"),
     ("densify.clean_iterations", [1, "x"],
      r"densify\.clean_iterations must be tuple\[int, \.\.\.\]"),
     ("init.box", [[0, 0], [1, 1]], "init.box must be tuple"),
     ("color.model", "rgb", "color.model must be 'neural' or 'sh', got 'rgb'"),
     ("optim.auxiliary_step", "both", "'separate' or 'joint'"),
     ("guard.step_limits", {"means": "big"}, "guard.step_limits must be dict"),
     ("dropout.rate", 1.0, r"dropout.rate must be in \[0, 1\)")],
)  # fmt: skip
def test_mistyped_values_name_the_dotted_field(name: str, value: Any, words: str) -> None:
    with pytest.raises(ConfigError, match=words):
        preset("llff", **{name: value})


def test_values_are_converted_by_their_type_hints() -> None:
    config = preset("llff", **{"photometric.lambda_dssim": 1, "init.box": [[0, 0, 0], [1, 2, 3]]})
    assert type(config.photometric.lambda_dssim) is float
    assert config.init.box == ((0.0, 0.0, 0.0), (1.0, 2.0, 3.0))
    assert preset("llff", background="white").background == (1.0, 1.0, 1.0)


def test_a_config_built_in_code_is_checked_by_its_hints_too() -> None:
    bad = dataclasses.replace(TrainConfig(), seed="zero")  # type: ignore[arg-type]
    with pytest.raises(ConfigError, match="seed must be int"):
        bad.validate()


def test_with_iterations_scales_exactly_the_schedule_fields() -> None:
    base = preset(
        "blender",
        iterations=6000,
        **{"densify.opacity_reset_interval": 3000, "color.view_degree_interval": 2000},
    )
    short = base.with_iterations(1500)
    before, after = flat_dict(base), flat_dict(short)
    changed = {k for k in before if before[k] != after[k]}
    # The flat version's list, spelled in dotted names: every other field is kept.
    old_list = ("lr_means_start", "lr_means_steps", "densify_from", "densify_until",
                "hard_depth_start", "soft_depth_start", "depth_until", "depth_smooth_start",
                "sh_degree_interval", "opacity_reset_interval", "consistency_start",
                "near_prune_start")  # fmt: skip
    new = {  # fields of later versions
        "correspondence.start",
        "correspondence.until",
        "binocular.start",
        "binocular.until",
        "color.view_degree_interval",
        "pseudo.start",
        "pseudo.until",
    }
    assert set(SCHEDULE_FIELDS) == {FLAT_NAMES[f] for f in old_list} | new
    assert changed <= {*SCHEDULE_FIELDS, "densify.clean_iterations", "iterations"}
    assert after["densify.opacity_reset_interval"] == 750
    assert after["color.view_degree_interval"] == 500
    assert after["depth.hard_start"] == 1  # a start of 0 becomes 1 when compressed


def test_parse_override_reads_dotted_names() -> None:
    assert parse_override("depth.soft_start=500") == ("depth.soft_start", 500)
    item = dict([parse_override("record.export=false")])
    assert apply_overrides(TrainConfig(), item).record.export is False
