"""Run one claimed job: load the uploaded scene, build the config, train, report, store.

The trainer's progress callback turns its records and state changes into stored events; a
heartbeat thread beside it renews the lease, publishes the iteration count and asks the
trainer to stop when the job was cancelled.
"""

from __future__ import annotations

import logging
import os
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from sparsesplat.api.artifacts import ArtifactMissing, ArtifactStoreError
from sparsesplat.api.disk import remove_partial_files
from sparsesplat.api.jobs import JobSpec, JobState, Record
from sparsesplat.api.settings import Settings
from sparsesplat.api.storage import Storage
from sparsesplat.api.store.jobs import Claim, JobStore
from sparsesplat.worker.artifact_sync import RunSync, kept_for_good
from sparsesplat.worker.camera_estimation import estimate_upload_cameras
from sparsesplat.worker.disk_guard import WriteSites
from sparsesplat.worker.heartbeat import JobHeartbeat
from sparsesplat.worker.run_spec import run_spec

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


MODEL_PARTIAL_NAME = "model.pt.tmp"
"""The finished model while it is written (renamed over ``checkpoint.pt`` when complete)."""


def run_job(
    claim: Claim, store: JobStore, storage: Storage, settings: Settings, beat: JobHeartbeat
) -> Outcome:
    """Train ``claim``'s job to the end (or until cancelled or shut down) under ``beat``;
    never raises for errors of the job itself (they become a failed outcome)."""
    from sparsesplat.engine.errors import EngineError

    spec = JobSpec.model_validate(claim.spec)
    run_dir = storage.run_dir(claim.job_id)
    sites = WriteSites(storage, claim.job_id)
    beat.on_phase = sites.enter
    sync = RunSync(storage, claim.job_id, allowed=lambda: not beat.lost)
    beat.start()
    try:
        run_dir.mkdir(parents=True, exist_ok=True)
        return _train(claim, spec, store, storage, settings, run_dir, beat, sync)
    except MemoryError:
        return Outcome(JobState.failed, "ran out of memory: try smaller images or fewer Gaussians")
    except ArtifactMissing as exc:
        return Outcome(JobState.failed, f"the job's files are missing from the artifact store: "
                                        f"{exc}")  # fmt: skip
    except ArtifactStoreError as exc:  # refused credentials, no bucket, a store that is down
        log.error("artifact store failed", extra={"error": str(exc)})
        return Outcome(JobState.failed, str(exc))
    except Exception as exc:
        # A write that failed (a full disk above all) fails the job naming the write, after
        # its partial files are gone: never a worker that dies and a job left running.
        written = sites.failure(exc, beat.trainer)
        if written is not None:
            log.error("job failed writing its files", extra={"error": written})
            return Outcome(JobState.failed, public_message(written, storage, claim.job_id))
        if isinstance(exc, EngineError):
            return Outcome(JobState.failed, public_message(str(exc), storage, claim.job_id))
        raise
    finally:
        sync.stop()
        beat.stop()
        if not beat.lost:  # else the job runs elsewhere now, and its partial files are its own
            remove_partial_files(storage.job_dir(claim.job_id))


def _train(
    claim: Claim,
    spec: JobSpec,
    store: JobStore,
    storage: Storage,
    settings: Settings,
    run_dir: Path,
    beat: JobHeartbeat,
    sync: RunSync,
) -> Outcome:
    from sparsesplat.engine.datasets import load_scene
    from sparsesplat.engine.model.checkpoint import CHECKPOINT_NAME
    from sparsesplat.engine.train import ProgressRecord, StateChange
    from sparsesplat.engine.train.run import RunPlan, build_run

    device = settings.device.value if settings.device.value != "auto" else _auto_device()
    beat.set_phase("preparing")
    # With a remote artifact store: the upload and the latest checkpoint come from the bucket
    # (this machine may never have seen the job, or trained it less far than another did).
    storage.fetch_upload(claim.job_id)
    storage.fetch_checkpoint(claim.job_id)
    estimate_upload_cameras(storage.upload_dir(claim.job_id), claim.job_id, store, beat, settings)
    storage.publish_upload(claim.job_id)  # the estimated cameras join the photos
    scene = load_scene(storage.upload_dir(claim.job_id), format="folder")

    def planned(plan: RunPlan) -> None:
        if plan.reason is not None:
            log.info("preset chosen", extra={"preset": plan.config.preset, "reason": plan.reason})
        for note in plan.notes:  # the result's metrics say it too (pose_refinement)
            log.info("run note", extra={"job_id": claim.job_id, "note": note})
        beat.set_preset(plan.config.preset, plan.reason)
        _carry_progress(store, claim.job_id, beat, plan.config.preset, plan.reason)
        if plan.config.uses_depth:
            beat.set_phase("depth prior")

    def got_priors(priors: list[Any]) -> None:
        pictures = [storage.prior_picture(claim.job_id, i) for i in range(len(priors))]
        _write_prior_pictures(priors, pictures)

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
            if not beat.lost:  # deleted, or another worker's now: its folder is not ours
                _write_series(records, run_dir, f"job {claim.job_id}: held-out error")
        elif isinstance(event, StateChange):
            beat.set_phase(event.state)
        return beat.cancel_requested

    checkpoint = run_dir / CHECKPOINT_NAME
    resume = checkpoint if checkpoint.exists() else None
    if resume is not None:
        log.info("resuming from checkpoint", extra={"job_id": claim.job_id})
    run = build_run(
        run_spec(spec, settings),
        scene,
        out_dir=run_dir,
        on_progress=on_progress,
        device=device,
        resume_from=resume,
        prior_cache_dir=run_dir / "priors",
        models_dir=settings.models_dir,
        on_plan=planned,
        on_priors=got_priors,
    )
    trainer, config = run.trainer, run.plan.config
    budget = config.time_budget_s
    beat.attach(trainer, config.iterations if budget is None else None, budget)
    sync.start()
    result = trainer.run()
    sync.stop()
    if not beat.lost and result.stopped:  # the checkpoint kept on stopping: resume needs it
        sync.push_changed()
    if beat.lost:
        return Outcome(JobState.queued, "lease lost to another worker")
    if beat.shutting_down and result.stopped:
        return Outcome(JobState.queued, "worker shut down; the job resumes from its checkpoint")
    if result.stopped:
        return Outcome(JobState.cancelled, "cancelled; the last checkpoint was kept")
    beat.set_phase("storing")
    disk_bytes = _keep_only_the_model(storage, claim.job_id, run_dir)
    # The final files are stored before the job is marked succeeded: a server on another
    # machine serves them from the store.
    sync.push_changed()
    storage.publish_run(claim.job_id, kept_for_good(storage, claim.job_id))
    for warning in result.metrics.get("warnings", []):
        store.add_warning(claim.job_id, public_message(str(warning), storage, claim.job_id))
    metrics = {k: _finite(v) for k, v in result.metrics.items() if isinstance(v, int | float)}
    outcome: dict[str, Any] = {
        "metrics": metrics,
        "n_gaussians": result.n_gaussians,
        "iterations": result.iteration,
        "background": [float(c) for c in trainer.background.tolist()],
        "disk_bytes": disk_bytes,
    }
    if trainer.poses is not None:  # the model is in the refined cameras' frame: serve those
        from sparsesplat.engine.datasets.trained_cameras import folder_trained_cameras

        upload = storage.upload_dir(claim.job_id)
        outcome["cameras"] = folder_trained_cameras(upload, scene, trainer.training_cameras())
    return Outcome(
        JobState.succeeded,
        f"trained {result.iteration} iterations in {result.seconds:.0f} s"
        + (f" of a {budget:g} s budget" if budget is not None else ""),
        outcome,
    )


def _keep_only_the_model(storage: Storage, job_id: str, run_dir: Path) -> int:
    """After success: the checkpoint becomes the stored model (no optimizer state, colour
    tables at half precision), the run's scratch files go (cached priors, temporary
    files; the prior pictures stay, a route serves them). Returns the job's bytes
    on disk, upload included."""
    import torch

    from sparsesplat.engine.model.checkpoint import (
        CHECKPOINT_NAME,
        load_checkpoint,
        model_state,
    )

    checkpoint = run_dir / CHECKPOINT_NAME
    if checkpoint.is_file():
        # Written beside the training checkpoint under its own partial name, then renamed over
        # it: a failure here leaves the training checkpoint whole and names this write.
        partial = run_dir / MODEL_PARTIAL_NAME
        torch.save(model_state(load_checkpoint(checkpoint)), partial)
        os.replace(partial, checkpoint)
    pictures = {storage.prior_picture(job_id, 0).parent}
    for path in sorted(run_dir.rglob("*"), reverse=True):  # files before their folders
        scratch = path.suffix == ".tmp" or (
            path.parent in pictures and path.is_file() and not path.name.startswith("view_")
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


def _auto_device() -> str:
    import torch

    return "cuda" if torch.cuda.is_available() else "cpu"
