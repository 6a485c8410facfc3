"""A job's spec -> the engine's run recipe: the spec's switches, its overrides, and the
deployment's settings. Used to train the job (``job_runner``) and to size it beforehand
(``disk_budget``)."""

from __future__ import annotations

from typing import Any

from sparsesplat.api.jobs import JobSpec
from sparsesplat.api.settings import Settings

SPEC_SWITCHES = {
    "depth_prior": "depth.prior",
    "color_model": "color.model",
    "hard_depth": "depth.hard",
    "soft_depth": "depth.soft",
    "background": "background",
    "init": "init.method",
    "dropout": "dropout.enabled",
    "dtu_background": "dtu.enabled",
    "consistency_weight": "consistency.weight",
    "near_prune": "near_prune.enabled",
    "depth_min_agreement": "depth.min_agreement",
    "eval_interval_s": "record.eval_interval_s",
}
"""The job spec's switches → the training config field each sets (when not None)."""


def run_spec(spec: JobSpec, settings: Settings | None = None) -> Any:
    """The engine's RunSpec for ``spec``: its switches, then its ``overrides``, then (with
    ``settings``) the deployment's thread count and checkpoint cadence, which are the
    deployment's and not the job's."""
    from sparsesplat.engine.train.run import RunSpec

    overrides: dict[str, Any] = {"seed": spec.seed}
    for key, name in SPEC_SWITCHES.items():
        value = getattr(spec, key)
        if value is not None:
            overrides[name] = value
    overrides.update(spec.overrides or {})
    if settings is not None:
        overrides["threads"] = settings.torch_threads
        overrides["record.checkpoint_interval_s"] = settings.checkpoint_interval_s
    return RunSpec(spec.preset, overrides, spec.iterations, spec.time_budget_s)


def build_config(
    spec: JobSpec, scene: Any, settings: Settings | None = None
) -> tuple[Any, str | None]:
    """The engine TrainConfig a spec asks for and why its preset was chosen from ``scene``
    (None when the spec named it): the run recipe's plan, as the job will train it."""
    from sparsesplat.engine.train.run import plan_run

    plan = plan_run(run_spec(spec, settings), scene)
    return plan.config, plan.reason
