"""Reading values into a :class:`TrainConfig`: dotted names, the old flat names, type hints.

One rule for every way a value arrives: ``--set part.field=JSON`` on the CLI, bench-quality's
``set:`` variants, a job's spec, a preset's data and a stored config read back from a
checkpoint. Names are dotted (``depth.soft_start``) or top-level (``seed``); the flat names of
earlier versions (``soft_depth_start``) are accepted through :data:`FLAT_NAMES`, so old
checkpoints and old command lines keep working. Values are checked and converted against the
dataclass type hints by ``values.py``.
"""

from __future__ import annotations

import dataclasses
import difflib
import functools
import json
from typing import Any

from sparsesplat.engine.errors import ConfigError
from sparsesplat.engine.model.raster import FLAT_RASTER_NAMES
from sparsesplat.engine.train.config.train_config import TrainConfig
from sparsesplat.engine.train.config.values import (
    checked,
    parse_background,
    sections,
    settable_fields,
)

FLAT_NAMES: dict[str, str] = {
    "init": "init.method",
    "init_box": "init.box",
    "init_points": "init.points",
    "init_points_density": "init.points_density",
    "init_points_min": "init.points_min",
    "init_points_max": "init.points_max",
    "init_opacity": "init.opacity",
    "dense_init_points": "init.dense_points",
    "dense_init_min_confidence": "init.dense_min_confidence",
    "dense_init_min_points": "init.dense_min_points",
    "color_model": "color.model",
    "sh_degree": "color.sh_degree",
    "sh_degree_interval": "color.sh_degree_interval",
    "hash_log2_size": "color.hash_log2_size",
    "hash_finest_resolution": "color.hash_finest_resolution",
    "lr_means_init": "optim.lr_means_init",
    "lr_means_final": "optim.lr_means_final",
    "lr_means_start": "optim.lr_means_start",
    "lr_means_steps": "optim.lr_means_steps",
    "lr_opacity": "optim.lr_opacity",
    "lr_scaling": "optim.lr_scaling",
    "lr_rotation": "optim.lr_rotation",
    "lr_hash_grid": "optim.lr_hash_grid",
    "lr_mlp": "optim.lr_mlp",
    "lr_sh": "optim.lr_sh",
    "adam_eps": "optim.adam_eps",
    "auxiliary_step": "optim.auxiliary_step",
    "lambda_dssim": "photometric.lambda_dssim",
    "shape_weight": "photometric.shape_weight",
    "scale_weight": "photometric.scale_weight",
    "opacity_weight": "photometric.opacity_weight",
    "depth_prior": "depth.prior",
    "depth_min_agreement": "depth.min_agreement",
    "hard_depth": "depth.hard",
    "soft_depth": "depth.soft",
    "hard_opacity": "depth.hard_opacity",
    "hard_depth_start": "depth.hard_start",
    "hard_depth_downscale": "depth.hard_downscale",
    "soft_depth_start": "depth.soft_start",
    "depth_every": "depth.every",
    "depth_until": "depth.until",
    "soft_depth_fused": "depth.soft_fused",
    "soft_depth_ema_gate": "depth.soft_ema_gate",
    "patch_min": "depth.patch_min",
    "patch_max": "depth.patch_max",
    "error_tolerance": "depth.error_tolerance",
    "depth_global_weight": "depth.global_weight",
    "depth_local_weight": "depth.local_weight",
    "depth_smooth_weight": "depth.smooth_weight",
    "depth_smooth_start": "depth.smooth_start",
    "depth_empty_background": "depth.empty_background",
    "densify_from": "densify.start",
    "densify_until": "densify.until",
    "densify_interval": "densify.interval",
    "densify_grad_threshold": "densify.grad_threshold",
    "percent_dense": "densify.percent_dense",
    "split_opacity_threshold": "densify.split_opacity_threshold",
    "prune_opacity": "densify.prune_opacity",
    "opacity_decay": "densify.opacity_decay",
    "opacity_reset_interval": "densify.opacity_reset_interval",
    "max_screen_size": "densify.max_screen_size",
    "max_world_size": "densify.max_world_size",
    "max_gaussians": "densify.max_gaussians",
    "clean_iterations": "densify.clean_iterations",
    "eval_interval_s": "record.eval_interval_s",
    "eval_every": "record.eval_every",
    "eval_max_views": "record.eval_max_views",
    "eval_lpips": "record.eval_lpips",
    "checkpoint_interval_s": "record.checkpoint_interval_s",
    "export": "record.export",
    "profile": "record.profile",
    "divergence_check_every": "guard.check_every",
    "divergence_step_limits": "guard.step_limits",
    "dropout": "dropout.enabled",
    "dropout_rate": "dropout.rate",
    "dropout_progressive": "dropout.progressive",
    "dtu_background": "dtu.enabled",
    "dtu_blacken_target": "dtu.blacken_target",
    "dtu_depth_fill": "dtu.depth_fill",
    "dtu_alpha_loss": "dtu.alpha_loss",
    "dtu_black_white": "dtu.black_white",
    "consistency_weight": "consistency.weight",
    "consistency_start": "consistency.start",
    "consistency_occlusion": "consistency.occlusion",
    "consistency_partners": "consistency.partners",
    "near_prune": "near_prune.enabled",
    "near_prune_radius": "near_prune.radius",
    "near_prune_start": "near_prune.start",
    "near_prune_every": "near_prune.every",
    **{flat: f"raster.{name}" for flat, name in FLAT_RASTER_NAMES.items()},
}
"""The flat field names of earlier versions (stored in their checkpoints, used in old
``--set`` lines and scripts) → the dotted name of the same field now."""

RETIRED_FIELDS = frozenset({"init_points_per_unit"})
"""Fields of earlier versions that no longer exist, ignored when a stored config is read."""


@functools.cache
def field_names() -> dict[str, Any]:
    """Every settable name of :class:`TrainConfig`, dotted for section fields, → its hint."""
    return settable_fields(TrainConfig)


def _suggest(name: str) -> str:
    candidates: dict[str, str] = {}
    for dotted in field_names():
        candidates[dotted] = dotted
        candidates.setdefault(dotted.rsplit(".", 1)[-1], dotted)
    for flat, dotted in FLAT_NAMES.items():
        candidates.setdefault(flat, dotted)
    close = difflib.get_close_matches(name, sorted(candidates), n=1, cutoff=0.6)
    return f"{name} (did you mean {candidates[close[0]]}?)" if close else name


def resolve(name: str) -> str:
    """The dotted name of field ``name`` (dotted, top-level or an old flat name);
    :class:`ConfigError` with a did-you-mean for an unknown one."""
    if name in field_names():
        return name
    if name in FLAT_NAMES:
        return FLAT_NAMES[name]
    raise ConfigError(f"unknown TrainConfig field(s): {_suggest(name)}")


def flatten(data: dict[str, Any]) -> dict[str, Any]:
    """A nested config dict (``to_dict``), a flat one of an earlier version, or a mix → one
    dict of names to values (sections' dicts become dotted names)."""
    out: dict[str, Any] = {}
    parts = sections(TrainConfig)
    for key, value in data.items():
        if key in parts and isinstance(value, dict):
            for sub, sub_value in value.items():
                out[f"{key}.{sub}"] = sub_value
        else:
            out[key] = value
    return out


def convert(name: str, value: Any) -> Any:
    """``value`` for dotted field ``name``, checked against its type hint and converted;
    :class:`ConfigError` naming the field and the type otherwise."""
    if name == "background":
        return parse_background(value)
    return checked(name, field_names()[name], value)


def apply_overrides(
    config: TrainConfig, overrides: dict[str, Any], stored: bool = False
) -> TrainConfig:
    """A validated copy of ``config`` with ``overrides`` (name → value, names as
    :func:`resolve` reads them) set. ``stored``: the dict is a stored config, whose retired
    fields (:data:`RETIRED_FIELDS`) are dropped. Unknown names all named in one error."""
    unknown = [
        k
        for k in overrides
        if k not in field_names() and k not in FLAT_NAMES and not (stored and k in RETIRED_FIELDS)
    ]
    if unknown:
        raise ConfigError(
            f"unknown TrainConfig field(s): {', '.join(_suggest(k) for k in sorted(unknown))}"
        )
    top: dict[str, Any] = {}
    per_section: dict[str, dict[str, Any]] = {}
    for key, value in overrides.items():
        if stored and key in RETIRED_FIELDS:
            continue
        name = resolve(key)
        converted = convert(name, value)
        if "." in name:
            section, sub = name.split(".", 1)
            per_section.setdefault(section, {})[sub] = converted
        else:
            top[name] = converted
    for section, changes in per_section.items():
        top[section] = dataclasses.replace(getattr(config, section), **changes)
    return dataclasses.replace(config, **top).validate()


def parse_override(item: str) -> tuple[str, Any]:
    """``FIELD=JSON`` → (field, value): the value as JSON when it parses (``0.3``, ``true``,
    ``[1, 2]``), else the plain string (``background=white``). The rule of the CLI's ``--set``
    and bench-quality's ``set:`` variants; the field (dotted, e.g. ``depth.soft_start``, or an
    old flat name) and the value are checked by :func:`apply_overrides`."""
    key, sep, value = item.partition("=")
    if not sep or not key:
        raise ConfigError(f"{item!r}: expected FIELD=JSON, e.g. depth.soft_start=500")
    try:
        return key, json.loads(value)
    except json.JSONDecodeError:
        return key, value


def flat_dict(config: TrainConfig) -> dict[str, Any]:
    """Every field of ``config`` by dotted name (the form ``--set`` and the docs use)."""
    return flatten(config.to_dict())


def config_from_dict(data: dict[str, Any]) -> TrainConfig:
    """The config ``data`` stores: the nested dict of :meth:`TrainConfig.to_dict`, also the
    flat dicts earlier versions stored (:data:`FLAT_NAMES`; retired fields dropped); unknown
    keys raise :class:`ConfigError`."""
    return apply_overrides(TrainConfig(), flatten(data), stored=True)
