"""The first phase of a photos-only job: estimate the cameras, store them with the upload.

The upload holds ``photos.json`` (``server/photo_upload.py``); this writes ``cameras.json``
(the one camera schema, so ``GET /v1/models/{id}`` returns the cameras the model was trained
in) and ``sparse_points.npz`` beside it, then the job trains from the folder as any upload.
A job resumed after estimation finds ``cameras.json`` and skips it. Photos that cannot be
placed raise the engine's CameraEstimationError, whose message names them: the job fails with
it and the photos stay stored. Photos the estimate left out (no match with the placed ones,
when enough of the set is placed) have no frame in ``cameras.json``, so the job trains on the
others; each is named in a warning.
"""

from __future__ import annotations

import json
import logging
from pathlib import Path

from sparsesplat.api.camera_estimation import CameraEstimation
from sparsesplat.api.cameras import Intrinsics
from sparsesplat.api.settings import Settings
from sparsesplat.api.storage import PHOTOS_FILE
from sparsesplat.api.store.jobs import JobStore
from sparsesplat.worker.heartbeat import JobHeartbeat

log = logging.getLogger("sparsesplat.worker")

PHASE = "estimating cameras"
"""The job's phase while its cameras are estimated."""


def estimate_upload_cameras(
    upload_dir: Path, job_id: str, store: JobStore, beat: JobHeartbeat, settings: Settings
) -> None:
    """Estimate and store the cameras of a photos-only upload; nothing when the upload has
    its ``cameras.json`` (uploaded, or estimated by an earlier attempt)."""
    if (upload_dir / "cameras.json").is_file() or not (upload_dir / PHOTOS_FILE).is_file():
        return
    from sparsesplat.engine.sfm import estimate_cameras
    from sparsesplat.engine.sfm.store import write_estimate

    manifest = json.loads((upload_dir / PHOTOS_FILE).read_text())
    intrinsics = manifest.get("intrinsics")
    beat.set_phase(PHASE)
    store.add_event(job_id, "progress", beat.progress().model_dump(mode="json"))
    estimate = estimate_cameras(
        [upload_dir / image for image in manifest["images"]],
        Intrinsics.model_validate(intrinsics) if intrinsics else None,
        threads=settings.torch_threads,
        labels=manifest["names"],
    )
    write_estimate(estimate, upload_dir / "cameras.json", manifest["images"])
    for photo in estimate.left_out:
        store.add_warning(job_id, f"{photo.reason} (the model is trained on the others)")
    summary = CameraEstimation.model_validate(estimate.summary())
    log.info("cameras estimated", extra={"job_id": job_id, **summary.model_dump()})
    beat.set_cameras(summary)
    beat.set_phase("preparing")
    store.add_event(job_id, "progress", beat.progress().model_dump(mode="json"))
