"""Run one claimed job: load the uploaded scene, build the config, train, report, store.

The trainer's progress callback turns its records and state changes into stored events; a
heartbeat thread beside it renews the lease, publishes the iteration count and asks the
trainer to stop when the job was cancelled.
"""

from __future__ import annotations

import json
import logging
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from sparsesplat.api.jobs import JobSpec, JobState, Record
from sparsesplat.api.settings import Settings
from sparsesplat.api.storage import Storage
from sparsesplat.api.store.jobs import Claim, JobStore
from sparsesplat.worker.heartbeat import JobHeartbeat

log = logging.getLogger("sparsesplat.worker")


@dataclass
class Outcome:
    """How a job ended in this worker."""

    state: JobState
    """Terminal state to store (or ``queued`` when the lease was lost)."""
    message: str
    """For the event and, when failed, the job's error."""
    result: dict[str, Any] | None = None
    """Final metrics and sizes when it succeeded."""


def build_config(spec: JobSpec, scene: Any) -> tuple[Any, str | None]:
    """The engine TrainConfig a spec asks for, and why its preset was chosen (None when the
    spec named it); the preset's reference schedule is compressed to the spec's length."""
    from sparsesplat.engine.train import preset

    reason = None
    name: str
    if spec.preset is not None:
        name = spec.preset
    else:
        name, reason = _preset_for(scene)
    overrides: dict[str, Any] = {"seed": spec.seed}
    for key in (
        "depth_prior",
        "color_model",
        "hard_depth",
        "soft_depth",
        "background",
        "init",
        "dropout",
        "dtu_background",
        "consistency_weight",
        "near_prune",
        "depth_min_agreement",
    ):
        value = getattr(spec, key)
        if value is not None:
            overrides[key] = "user" if (key == "depth_prior" and value == "uploaded") else value
    if spec.record_interval_s is not None:
        overrides["eval_interval_s"] = spec.record_interval_s
    config = preset(name, iterations=spec.iterations, **overrides)
    return config, reason


def _preset_for(scene: Any) -> tuple[str, str]:
    """The engine's choice from the scene's background and camera layout, and why."""
    from sparsesplat.engine.datasets.common import choose_preset

    name, reason = choose_preset(scene)
    log.info("preset chosen", extra={"preset": name, "reason": reason})
    return name, reason


def run_job(
    claim: Claim, store: JobStore, storage: Storage, settings: Settings, beat: JobHeartbeat
) -> Outcome:
    """Train ``claim``'s job to the end (or until cancelled or shut down) under ``beat``;
    never raises for errors of the job itself (they become a failed outcome)."""
    from sparsesplat.engine.errors import EngineError

    spec = JobSpec.model_validate(claim.spec)
    run_dir = storage.run_dir(claim.job_id)
    run_dir.mkdir(parents=True, exist_ok=True)
    beat.start()
    try:
        return _train(claim, spec, store, storage, settings, run_dir, beat)
    except EngineError as exc:
        return Outcome(JobState.failed, public_message(str(exc), storage, claim.job_id))
    except MemoryError:
        return Outcome(JobState.failed, "ran out of memory: try smaller images or fewer Gaussians")
    finally:
        beat.stop()


def _train(
    claim: Claim,
    spec: JobSpec,
    store: JobStore,
    storage: Storage,
    settings: Settings,
    run_dir: Path,
    beat: JobHeartbeat,
) -> Outcome:
    from sparsesplat.engine.datasets import load_scene
    from sparsesplat.engine.train import ProgressRecord, StateChange, Trainer
    from sparsesplat.engine.train.budget import iterations_for_budget
    from sparsesplat.engine.train.checkpoint import CHECKPOINT_NAME

    device = settings.device.value if settings.device.value != "auto" else _auto_device()
    beat.set_phase("preparing")
    scene = load_scene(storage.upload_dir(claim.job_id), format="folder")
    config, reason = build_config(spec, scene)
    beat.set_preset(config.preset, reason)
    _carry_progress(store, claim.job_id, beat, config.preset, reason)
    config = _with_service_settings(config, settings)
    priors = None
    if config.uses_depth:
        from sparsesplat.engine.priors import compute_priors

        beat.set_phase("depth prior")
        priors = compute_priors(
            scene, config.depth_prior, cache_dir=run_dir / "priors", models_dir=settings.models_dir
        )
        pictures = [storage.prior_picture(claim.job_id, i) for i in range(len(priors))]
        _write_prior_pictures(priors, pictures)
    checkpoint = run_dir / CHECKPOINT_NAME
    if spec.time_budget_s is not None and not checkpoint.exists():
        beat.set_phase("timing")
        n = iterations_for_budget(scene, config, priors, spec.time_budget_s, device)
        config = _with_length(spec, config, n, settings)
        (run_dir / "budget.json").write_text(f'{{"iterations": {n}}}')
    elif spec.time_budget_s is not None and (run_dir / "budget.json").exists():
        n = int(json.loads((run_dir / "budget.json").read_text())["iterations"])
        config = _with_length(spec, config, n, settings)
    records: list[dict[str, Any]] = []

    def on_progress(event: Any) -> bool:
        if isinstance(event, ProgressRecord):
            data = event.to_dict()
            records.append(data)
            record = Record.model_validate(
                {k: v for k, v in data.items() if k in Record.model_fields}
            )
            store.add_event(claim.job_id, "record", record.model_dump(mode="json"))
            beat.set_record(record)
            _write_series(records, run_dir, f"job {claim.job_id}: held-out error")
        elif isinstance(event, StateChange):
            beat.set_phase(event.state)
        return beat.cancel_requested

    resume = checkpoint if checkpoint.exists() else None
    if resume is not None:
        log.info("resuming from checkpoint", extra={"job_id": claim.job_id})
    trainer = Trainer(scene, config, priors, run_dir, on_progress, device, resume)
    beat.attach(trainer, config.iterations)
    result = trainer.run()
    if beat.lost:
        return Outcome(JobState.queued, "lease lost to another worker")
    if beat.shutting_down and result.stopped:
        return Outcome(JobState.queued, "worker shut down; the job resumes from its checkpoint")
    if result.stopped:
        return Outcome(JobState.cancelled, "cancelled; the last checkpoint was kept")
    beat.set_phase("storing")
    disk_bytes = _keep_only_the_model(storage, claim.job_id, run_dir)
    for warning in result.metrics.get("warnings", []):
        store.add_warning(claim.job_id, public_message(str(warning), storage, claim.job_id))
    metrics = {k: _finite(v) for k, v in result.metrics.items() if isinstance(v, int | float)}
    return Outcome(
        JobState.succeeded,
        f"trained {result.iteration} iterations in {result.seconds:.0f} s",
        {
            "metrics": metrics,
            "n_gaussians": result.n_gaussians,
            "iterations": result.iteration,
            "background": [float(c) for c in trainer.background.tolist()],
            "disk_bytes": disk_bytes,
        },
    )


def _keep_only_the_model(storage: Storage, job_id: str, run_dir: Path) -> int:
    """After success: the checkpoint becomes the stored model (no optimizer state, colour
    tables at half precision), the run's scratch files go (cached priors, the budget note,
    temporary files; the prior pictures stay, a route serves them). Returns the job's bytes
    on disk, upload included."""
    from sparsesplat.engine.train.checkpoint import (
        CHECKPOINT_NAME,
        load_checkpoint,
        model_state,
        save_checkpoint,
    )

    checkpoint = run_dir / CHECKPOINT_NAME
    if checkpoint.is_file():
        save_checkpoint(model_state(load_checkpoint(checkpoint)), checkpoint)
    pictures = {storage.prior_picture(job_id, 0).parent}
    for path in sorted(run_dir.rglob("*"), reverse=True):  # files before their folders
        scratch = (
            path.name == "budget.json"
            or path.suffix == ".tmp"
            or (path.parent in pictures and path.is_file() and not path.name.startswith("view_"))
        )
        if path.is_file() and scratch:
            path.unlink()
        elif path.is_dir() and path not in pictures and not any(path.iterdir()):
            path.rmdir()
    return sum(p.stat().st_size for p in storage.job_dir(job_id).rglob("*") if p.is_file())


def _carry_progress(
    store: JobStore, job_id: str, beat: JobHeartbeat, preset: str, reason: str | None
) -> None:
    """A resumed attempt starts from what the last one published: its latest held-out record
    and why its preset was chosen (otherwise the progress reads null until the next record)."""
    job = store.get(job_id)
    previous = job.progress if job is not None else None
    if previous is None:
        return
    if previous.last_record is not None:
        beat.set_record(previous.last_record)
    if reason is None and previous.preset == preset and previous.preset_reason is not None:
        beat.set_preset(preset, previous.preset_reason)


def public_message(message: str, storage: Storage, job_id: str) -> str:
    """``message`` with the server's folders taken out: the engine names files by their path,
    and a user reads them relative to their upload (``cameras.json``, ``images/000.png``)."""
    for folder in (storage.upload_dir(job_id), storage.run_dir(job_id), storage.root):
        for form in {str(folder), str(folder.resolve())}:
            message = message.replace(form + "/", "").replace(form, "the job's folder")
    return message


def _write_prior_pictures(priors: list[Any], pictures: list[Path]) -> None:
    """One PNG per training view: the prior normalised to its own range (near = bright)."""
    import numpy as np
    from PIL import Image

    for prior, path in zip(priors, pictures, strict=True):
        depth = prior.depth.detach().cpu().numpy().astype(np.float64)
        lo, hi = np.percentile(depth, 1), np.percentile(depth, 99)
        scaled = 1.0 - np.clip((depth - lo) / (hi - lo if hi > lo else 1.0), 0.0, 1.0)
        path.parent.mkdir(parents=True, exist_ok=True)
        Image.fromarray((scaled * 255 + 0.5).astype(np.uint8)).save(path)


def _finite(value: float) -> float | None:
    return value if value == value and abs(value) != float("inf") else None


def _write_series(records: list[dict[str, Any]], run_dir: Path, title: str) -> None:
    """Keep the error-against-time files (JSON, CSV, plot titled ``title``) current while the
    run goes."""
    from sparsesplat.engine.report import write_report

    try:
        write_report(records, run_dir, plot=True, title=title)
    except Exception:  # a plot is a convenience: never fail a job over it
        log.warning("could not write the metrics series", exc_info=True)


def _with_length(spec: JobSpec, config: Any, iterations: int, settings: Settings) -> Any:
    """``config`` rebuilt for a run of ``iterations`` (a time budget's), its preset's schedule
    compressed from the reference; the preset already chosen is kept, not chosen again."""
    sized = spec.model_copy(update={"preset": config.preset, "iterations": iterations})
    return _with_service_settings(build_config(sized, None)[0], settings)


def _with_service_settings(config: Any, settings: Settings) -> Any:
    """Thread count and checkpoint cadence are the deployment's, not the job's."""
    import dataclasses

    return dataclasses.replace(
        config,
        threads=settings.torch_threads,
        checkpoint_interval_s=settings.checkpoint_interval_s,
    )


def _auto_device() -> str:
    import torch

    return "cuda" if torch.cuda.is_available() else "cpu"
