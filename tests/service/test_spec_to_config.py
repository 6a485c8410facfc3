"""A job's spec becomes the engine's training config: each switch a user sets reaches its
field, and a switch left out keeps the preset's value."""

from __future__ import annotations

import argparse

import pytest
from pydantic import ValidationError

from sparsesplat.api.jobs import JobSpec
from sparsesplat.api.settings import Settings
from sparsesplat.engine.commands import train as train_command
from sparsesplat.engine.train import preset
from sparsesplat.engine.train.config import ConfigError
from sparsesplat.engine.train.config.overrides import flat_dict
from sparsesplat.engine.train.config.presets import PRESET_ITERATIONS
from sparsesplat.engine.train.run import plan_run
from sparsesplat.worker.run_spec import build_config, run_spec


def test_unset_switches_keep_the_presets_values() -> None:
    config, reason = build_config(JobSpec(preset="dtu"), scene=None)
    assert reason is None
    want = preset("dtu")
    fields = ("init.method", "dropout.enabled", "dtu.enabled", "consistency.weight")
    fields += ("near_prune.enabled", "depth.min_agreement", "color.model")
    got, wanted = flat_dict(config), flat_dict(want)
    for field in fields:
        assert got[field] == wanted[field], field


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
    parts = (off.init.method, off.dropout.enabled, off.dtu.enabled, off.consistency.weight)
    assert (*parts, off.near_prune.enabled, off.depth.min_agreement) == (
        "random", False, False, 0.0, False, None)  # fmt: skip
    config, _ = build_config(spec, scene=None)
    assert config.init.method == "dense"
    assert config.dropout.enabled is True
    assert config.dtu.enabled is True
    assert config.consistency.weight == pytest.approx(0.1)
    assert config.near_prune.enabled is True
    assert config.depth.min_agreement == pytest.approx(0.3)
    assert config.iterations == 1200


def test_run_length_is_the_presets_default_or_the_reference_schedule_compressed() -> None:
    default, _ = build_config(JobSpec(preset="llff"), scene=None)
    assert default.iterations == PRESET_ITERATIONS["llff"]
    asked, _ = build_config(JobSpec(preset="llff", iterations=3000), scene=None)
    assert (asked.iterations, asked.densify.until) == (3000, 3000)  # longer than the default
    # a time budget keeps the preset's default schedule, which the deadline clock follows;
    # the deployment's settings come last
    budget, _ = build_config(
        JobSpec(preset="dtu", dropout=True, time_budget_s=90), None, Settings(torch_threads=1)
    )
    assert (budget.preset, budget.iterations, budget.time_budget_s) == ("dtu", 1500, 90.0)
    assert budget.dropout.enabled is True and budget.threads == 1


def _cli_args(*argv: str) -> argparse.Namespace:
    parser = argparse.ArgumentParser()
    train_command.add_arguments(parser)
    return parser.parse_args(["scene", "--out", "o", *argv])


def test_a_job_and_the_cli_with_the_same_settings_build_equal_configs() -> None:
    """The embedded and Celery workers (``run_job``) and ``sparsesplat train`` share the run
    recipe (``engine.train.run``): the same settings, spelled each one's way, give one config."""
    spec = JobSpec(
        preset="llff", seed=3, depth_prior="plane_sweep", color_model="sh", dropout=False,
        eval_interval_s=5, iterations=700, background=(1.0, 1.0, 1.0),
        overrides={"depth.soft_start": 120, "photometric.lambda_dssim": 0.3},
    )  # fmt: skip
    args = _cli_args(
        "--preset", "llff", "--seed", "3", "--prior", "plane_sweep", "--iterations", "700",
        "--set", 'color.model="sh"', "--set", "dropout=false", "--set", "eval_interval_s=5",
        "--set", "background=white", "--set", "depth.soft_start=120",
        "--set", "lambda_dssim=0.3",
    )  # fmt: skip
    job = plan_run(run_spec(spec), None).config
    cli = plan_run(train_command.run_spec(args), None).config
    assert job == cli
    assert (job.depth.soft_start, job.color.model, job.record.eval_interval_s) == (120, "sh", 5)
    # a budget likewise
    job = plan_run(run_spec(JobSpec(preset="dtu", time_budget_s=60)), None).config
    cli = plan_run(train_command.run_spec(_cli_args("--preset", "dtu", "--time-budget", "60")),
                   None).config  # fmt: skip
    assert job == cli and job.time_budget_s == 60.0


def test_old_spellings_of_the_spec_still_read() -> None:
    """Stored jobs and older clients: ``record_interval_s`` and depth prior ``uploaded``."""
    old = JobSpec.model_validate({"record_interval_s": 5, "depth_prior": "uploaded"})
    assert old == JobSpec(eval_interval_s=5, depth_prior="user")
    with pytest.raises(ValidationError, match="eval_interval_s"):
        JobSpec.model_validate({"record_interval_s": 5, "eval_interval_s": 6})


def test_a_bad_override_in_a_spec_names_the_dotted_field() -> None:
    spec = JobSpec(preset="llff", overrides={"depth.soft_strat": 5})
    with pytest.raises(ConfigError, match=r"depth\.soft_strat \(did you mean depth\.soft_start"):
        build_config(spec, None)


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


def test_a_job_and_the_cli_get_the_same_layout_recipe_on_a_scene() -> None:
    """With a scene to look at, both paths take the preset's recipe for its training cameras'
    layout (the synthetic scene's cameras face forward): a job trains what ``sparsesplat
    train`` trains."""
    from sparsesplat.engine.synthetic import make_scene

    scene, _ = make_scene(seed=0)
    forward = preset("llff", layout="forward-facing", seed=0)
    job = build_config(JobSpec(preset="llff", seed=0), scene=scene)[0]
    cli = plan_run(train_command.run_spec(_cli_args("--preset", "llff", "--seed", "0")), scene)
    assert job == cli.config == forward
    assert forward.init.method == "dense" and forward != preset("llff", seed=0)
    # a job that names its init keeps the preset's base recipe, as the CLI does
    named = build_config(JobSpec(preset="llff", seed=0, init="random"), scene=scene)[0]
    assert named == preset("llff", seed=0, **{"init.method": "random"})
