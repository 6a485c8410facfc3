"""The run recipe: what to train (preset, overrides, length or time budget) on a scene -> a
ready :class:`Trainer`.

One recipe for ``sparsesplat train``, the embedded worker and the Celery worker: choose the
preset (from the scene when none is named), build its config (the reference schedule
compressed to the run length; under a time budget the preset's default length is the nominal
schedule the deadline clock follows), compute the depth priors, build the trainer. Each caller
only translates its own input (command-line arguments, a job's spec) into a :class:`RunSpec`.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from sparsesplat.engine.datasets.common import camera_layout
from sparsesplat.engine.scene import Scene
from sparsesplat.engine.threads import torch_threads
from sparsesplat.engine.train.config import ConfigError, TrainConfig
from sparsesplat.engine.train.config.overrides import resolve
from sparsesplat.engine.train.config.presets import choose_preset, pose_recipe, preset
from sparsesplat.engine.train.loop.progress import ProgressCallback
from sparsesplat.engine.train.loop.trainer import Trainer


@dataclass(frozen=True)
class RunSpec:
    """What to train, however it was asked for (command line or job spec)."""

    preset: str | None = None
    """Preset name; None chooses one from the scene (``config.presets.choose_preset``)."""
    overrides: dict[str, Any] = field(default_factory=dict)
    """Config values by dotted (or old flat) name, applied after the preset's schedule is
    compressed (``iterations`` here means the run length, as :attr:`iterations`)."""
    iterations: int | None = None
    """Run length; None: the preset's default (``presets.PRESET_ITERATIONS``)."""
    time_budget_s: float | None = None
    """Train until this many training seconds are spent instead (exclusive with
    ``iterations``); the schedule follows the elapsed fraction of the budget."""


@dataclass(frozen=True)
class RunPlan:
    """The config a :class:`RunSpec` resolves to on a scene."""

    config: TrainConfig
    """The validated training config."""
    reason: str | None
    """Why its preset was chosen from the scene; None when the spec named it."""
    notes: tuple[str, ...] = ()
    """What the scene's facts add to the preset whichever it is, one phrase each (the
    training poses refined: ``presets.pose_recipe``)."""


@dataclass
class PreparedRun:
    """A trainer ready to :meth:`Trainer.run`, with what went into it."""

    trainer: Trainer
    """The built trainer (resumed from its checkpoint when one was given)."""
    plan: RunPlan
    """Its config and the preset's reason."""
    priors: list[Any] | None
    """The depth priors (None without depth)."""


def plan_run(spec: RunSpec, scene: Scene | None) -> RunPlan:
    """The config ``spec`` asks for on ``scene``: the preset (chosen from ``scene`` when the
    spec names none) with its recipe for the training cameras' layout and the poses refined
    when the cameras are uncertain (``presets.pose_recipe``), then the spec's overrides.
    ``scene`` None: no layout recipe (the trainer resolves the preset's ``auto`` fields when
    it starts). :class:`ConfigError` names a bad preset, field, value or length."""
    overrides = dict(spec.overrides)
    iterations = spec.iterations
    lengths = [k for k in overrides if resolve(k) == "iterations"]
    if lengths:  # ``--set iterations=N`` means the run length
        if iterations is not None or len(lengths) > 1:
            raise ConfigError("give the run length once (iterations), not twice")
        iterations = overrides.pop(lengths[0])
    budget = spec.time_budget_s
    budgeted = [k for k in overrides if resolve(k) == "time_budget_s"]
    if budgeted:
        if budget is not None or len(budgeted) > 1:
            raise ConfigError("give the time budget once (time_budget_s), not twice")
        budget = overrides.pop(budgeted[0])
    if budget is not None:
        if iterations is not None:
            raise ConfigError("give either iterations or a time budget, not both")
        if not (isinstance(budget, int | float) and math.isfinite(budget) and budget > 0):
            raise ConfigError(f"time budget must be a positive number of seconds, got {budget}")
    reason = None
    if spec.preset is not None:
        name = spec.preset
    elif scene is not None:
        name, reason = choose_preset(scene)
    else:
        raise ConfigError("no preset named and no scene to choose one from")
    if budget is not None:  # as an override, it replaces the default length's time limit
        overrides["time_budget_s"] = float(budget)
    refine, note = pose_recipe(None if scene is None else scene.pose_std_deg, overrides)
    # The recipe first, so that an override of one of its settings (poses.lr) wins; resolved
    # names, so that an old flat spelling of the same field replaces it too.
    refine = {k: v for k, v in refine.items() if all(resolve(o) != k for o in overrides)}
    config = preset(
        name, iterations=iterations, layout=training_layout(scene), **refine, **overrides
    )
    return RunPlan(config, reason, () if note is None else (note,))


def training_layout(scene: Scene | None) -> str | None:
    """How the scene's training cameras are laid out (``CameraLayout.kind``), which picks the
    preset's recipe for it; None without a scene or training views."""
    if scene is None or not scene.train:
        return None
    return camera_layout([view.camera for view in scene.train]).kind


def build_run(
    spec: RunSpec,
    scene: Scene,
    *,
    out_dir: str | Path | None = None,
    on_progress: ProgressCallback | None = None,
    device: str = "cpu",
    resume_from: str | Path | None = None,
    prior_cache_dir: Path | None = None,
    models_dir: Path | None = None,
    on_plan: Callable[[RunPlan], None] | None = None,
    on_priors: Callable[[list[Any]], None] | None = None,
    time_source: Callable[[], float] = time.perf_counter,
    prior_source: Callable[[Scene, str], Sequence[Any]] | None = None,
    init_depth: list[Any] | None = None,
) -> PreparedRun:
    """Plan ``spec`` on ``scene``, compute its depth priors and build the trainer.

    ``on_plan``: called with the plan before the priors are computed (to announce the preset,
    load native code); ``on_priors``: called with the priors once computed. ``prior_source``:
    where the priors of a kind come from in place of :func:`compute_priors` (a benchmark's
    per-process cache, a synthetic scene's exact depths); it is asked only when the config
    uses depth. The other arguments go to :func:`compute_priors` and :class:`Trainer`."""
    plan = plan_run(spec, scene)
    if on_plan is not None:
        on_plan(plan)
    config = plan.config
    # The run's thread count from its first step: the priors' network and the start's plane
    # sweep sum in another order on another count, and a seeded run must not depend on the
    # process's default (the service's workers and the CLI differ there).
    with torch_threads(config.threads):
        priors: list[Any] | None = None
        if config.uses_depth:
            kind = config.depth.prior
            if prior_source is not None:
                priors = list(prior_source(scene, kind))
            else:
                from sparsesplat.engine.priors import compute_priors

                priors = list(
                    compute_priors(scene, kind, cache_dir=prior_cache_dir, models_dir=models_dir)
                )
            if on_priors is not None:
                on_priors(priors)
        trainer = Trainer(
            scene,
            config,
            priors,
            out_dir,
            on_progress,
            device,
            resume_from,
            init_depth,
            time_source=time_source,
        )
    return PreparedRun(trainer, plan, priors)
