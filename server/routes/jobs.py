"""``/v1/jobs``: submit, list, read, cancel and delete training jobs, and read their metrics."""

from __future__ import annotations

import asyncio
import csv
import io
import json
from typing import Annotated

import sqlalchemy.exc
from fastapi import APIRouter, Header, Path, Query, Request, Response
from fastapi.responses import FileResponse
from starlette.formparsers import MultiPartException

from sparsesplat.api.artifacts import ArtifactMissing
from sparsesplat.api.disk import disk_full_message, free_bytes, is_disk_full
from sparsesplat.api.jobs import Job, JobPage, JobState, Record
from sparsesplat.api.storage import PHOTOS_FILE
from sparsesplat.api.store.jobs import new_job_id
from sparsesplat.server.deps import OwnerDep, OwnJobDep, ServiceDep
from sparsesplat.server.errors import ServiceError, invalid, not_found
from sparsesplat.server.state import ServiceState
from sparsesplat.server.storage_limits import check_submission, declared_length
from sparsesplat.server.uploads import validate_upload

router = APIRouter(prefix="/v1/jobs", tags=["jobs"])

RECORD_COLUMNS = list(Record.model_fields)
"""Columns of the CSV form of a job's metrics."""


UPLOAD_SCHEMA = {
    "requestBody": {
        "required": True,
        "content": {
            "multipart/form-data": {
                "schema": {
                    "type": "object",
                    "required": ["images"],
                    "properties": {
                        "cameras": {
                            "type": "string",
                            "format": "binary",
                            "description": "cameras.json (see api/cameras.py); without it the "
                            "images are photos whose cameras the job estimates first",
                        },
                        "intrinsics": {
                            "type": "string",
                            "description": "photos without cameras: shared pinhole intrinsics "
                            "as JSON {fx, fy, cx, cy} in pixels, held fixed",
                        },
                        "images": {
                            "type": "array",
                            "items": {"type": "string", "format": "binary"},
                            "description": "one PNG/JPEG/WebP per frame, by file name",
                        },
                        "depths": {
                            "type": "array",
                            "items": {"type": "string", "format": "binary"},
                            "description": "optional depth maps named by the frames",
                        },
                        "masks": {
                            "type": "array",
                            "items": {"type": "string", "format": "binary"},
                            "description": "optional object masks named by the frames",
                        },
                        "spec": {"type": "string", "description": "JobSpec as JSON"},
                    },
                }
            }
        },
    }
}
"""The multipart body of ``POST /v1/jobs``, for the OpenAPI schema (parsed by hand below so
limits apply before anything is kept)."""


@router.post(
    "",
    status_code=201,
    response_model=Job,
    summary="Submit a training job",
    openapi_extra=UPLOAD_SCHEMA,
)
async def submit_job(
    request: Request,
    response: Response,
    service: ServiceDep,
    owner: OwnerDep,
    idempotency_key: Annotated[str | None, Header(max_length=200)] = None,
) -> Job:
    """Multipart upload: ``cameras`` (cameras.json), ``images`` (one per frame), optional
    ``depths``, ``masks`` and ``spec`` (JSON JobSpec); or, without ``cameras``, photos whose
    cameras the job estimates first (optional ``intrinsics``). With an ``Idempotency-Key`` a retried
    submission returns the first job (200) instead of creating a second one."""
    settings = service.settings
    if idempotency_key is not None:
        existing = await asyncio.to_thread(
            service.jobs.find_by_idempotency_key, owner, idempotency_key
        )
        if existing is not None:
            response.status_code = 200
            response.headers["Location"] = f"/v1/jobs/{existing.id}"
            return existing
    active = await asyncio.to_thread(service.jobs.count_active, owner)
    if active >= settings.max_active_jobs_per_key:
        raise ServiceError(
            429,
            "too_many_jobs",
            f"{active} jobs are queued or running for this key; the limit is "
            f"{settings.max_active_jobs_per_key} (SPARSESPLAT_MAX_ACTIVE_JOBS_PER_KEY)",
            {"Retry-After": "60"},
        )
    # The key's limits and the disk's room, before anything is read or stored.
    upload_bytes = declared_length(dict(request.headers))
    await asyncio.to_thread(check_submission, service, owner, upload_bytes)
    try:
        form = await request.form(max_files=2 * settings.max_images + 4, max_fields=16)
    except MultiPartException as exc:
        raise invalid("invalid_upload", f"cannot read the multipart upload: {exc.message}") from exc
    try:
        staging = service.storage.new_staging_dir()
    except OSError as exc:
        await form.close()
        if is_disk_full(exc):
            raise _no_room(service, upload_bytes) from exc
        raise
    try:
        try:
            upload = await asyncio.to_thread(validate_upload, form, settings, staging)
        except OSError as exc:  # the staged files could not be written
            if is_disk_full(exc):
                raise _no_room(service, upload_bytes) from exc
            raise
        # Files first, record second: a worker that claims the job finds its upload in place.
        job_id = new_job_id()
        await asyncio.to_thread(service.storage.commit_upload, staging, job_id)
        try:
            job, created = await asyncio.to_thread(
                service.jobs.create, job_id, owner, upload.spec, upload.n_train_views,
                upload.n_test_views, idempotency_key,
            )  # fmt: skip
        except BaseException:
            service.storage.delete_job(job_id)
            raise
        if created:
            await asyncio.to_thread(service.dispatch.enqueue, job_id)
        else:  # a concurrent retry with the same idempotency key won the race
            service.storage.delete_job(job_id)
            response.status_code = 200
    finally:
        service.storage.discard(staging)
        await form.close()
    response.headers["Location"] = f"/v1/jobs/{job.id}"
    return job


def _no_room(service: ServiceState, upload_bytes: int) -> ServiceError:
    """507 for an upload the disk had no room for (its staged files are removed by the
    caller)."""
    free = free_bytes(service.storage.root)
    message = disk_full_message("receiving the upload", upload_bytes or None, free)
    return ServiceError(507, "insufficient_storage", message, {"Retry-After": "60"})


@router.get("", response_model=JobPage, summary="List your jobs")
def list_jobs(
    service: ServiceDep,
    owner: OwnerDep,
    state: JobState | None = None,
    cursor: str | None = None,
    limit: Annotated[int, Query(ge=1, le=100)] = 20,
) -> JobPage:
    """Your jobs, newest first; follow ``next_cursor`` for older ones."""
    try:
        page, next_cursor = service.jobs.page(owner, state, cursor, limit)
    except ValueError as exc:
        raise invalid("invalid_cursor", str(exc)) from exc
    return JobPage(jobs=page, next_cursor=next_cursor)


@router.get("/{job_id}", response_model=Job, summary="Read a job")
def get_job(job: OwnJobDep) -> Job:
    """State, queue position or progress, and the error of a failed job."""
    return job


@router.post("/{job_id}/cancel", response_model=Job, summary="Cancel a job")
def cancel_job(job: OwnJobDep, service: ServiceDep) -> Job:
    """A queued job is cancelled at once; a running one stops at its next iteration (its
    worker is ended if it has not stopped within the grace period). Terminal jobs are left as
    they are."""
    updated = service.jobs.request_cancel(job.id)
    if updated is None:  # deleted between the ownership check and the request
        raise not_found("job", job.id)
    return updated


@router.delete("/{job_id}", status_code=204, summary="Delete a job and every file of it")
def delete_job(job: OwnJobDep, service: ServiceDep) -> Response:
    """Cancels it if needed, then removes its record, events, uploads, model and exports.
    On a full disk its files go first, so that the database has room to forget it (a 507 if
    it still has not: the files are gone all the same, and a retry removes the record)."""

    def forget() -> None:
        if not job.state.terminal:
            service.jobs.request_cancel(job.id)
        service.jobs.delete(job.id)

    try:
        forget()
    except sqlalchemy.exc.OperationalError as exc:
        if not is_disk_full(exc):
            raise
        service.storage.delete_job(job.id)
        forget()
    service.storage.delete_job(job.id)
    return Response(status_code=204)


@router.get("/{job_id}/metrics", summary="Held-out error against run time")
def get_metrics(
    job: OwnJobDep,
    service: ServiceDep,
    format: Annotated[str, Query(pattern="^(json|csv)$")] = "json",
) -> Response:
    """The error-vs-time records so far (JSON list or CSV), one per evaluation."""
    records = [
        e.data for e in service.jobs.events_after(job.id, 0, limit=100_000) if e.type == "record"
    ]
    if format == "json":
        return Response(json.dumps(records), media_type="application/json")
    buffer = io.StringIO()
    writer = csv.DictWriter(buffer, fieldnames=RECORD_COLUMNS, extrasaction="ignore")
    writer.writeheader()
    for record in records:
        writer.writerow({k: "" if record.get(k) is None else record.get(k) for k in RECORD_COLUMNS})
    return Response(buffer.getvalue(), media_type="text/csv")


@router.get("/{job_id}/metrics.png", summary="Plot of held-out error against run time")
def get_metrics_plot(job: OwnJobDep, service: ServiceDep) -> FileResponse:
    """PSNR, SSIM, LPIPS and AVGE against training seconds (redrawn at every record)."""
    try:  # redrawn while the job runs: the stored one is the latest
        path = service.storage.fetch(service.storage.artifact(job.id, "series_png"), fresh=True)
    except ArtifactMissing:
        raise ServiceError(
            404, "plot_not_ready", "no held-out record yet: the plot appears with the first one"
        ) from None
    return FileResponse(path, media_type="image/png")


@router.get("/{job_id}/images/{index}", summary="An uploaded image")
def get_image(
    job: OwnJobDep, service: ServiceDep, index: Annotated[int, Path(ge=0)]
) -> FileResponse:
    """The ``index``-th frame's image as uploaded (frames in ``cameras.json`` order)."""
    storage = service.storage
    upload = storage.upload_dir(job.id)
    if storage.has(upload / "cameras.json"):
        frames = json.loads(storage.fetch(upload / "cameras.json").read_text())["frames"]
    else:  # photos without cameras, not estimated yet (server/photo_upload.py)
        manifest = json.loads(storage.fetch(upload / PHOTOS_FILE).read_text())
        frames = [{"image": image} for image in manifest["images"]]
    if index >= len(frames):
        raise ServiceError(
            404, "image_not_found",
            f"job {job.id} has {len(frames)} images: indices 0 to {len(frames) - 1}",
        )  # fmt: skip
    path = storage.fetch(upload / frames[index]["image"])
    return FileResponse(path, media_type=_IMAGE_TYPES.get(path.suffix, "application/octet-stream"))


@router.get("/{job_id}/priors/{index}", summary="A training view's depth prior, as a picture")
def get_prior(
    job: OwnJobDep, service: ServiceDep, index: Annotated[int, Path(ge=0)]
) -> FileResponse:
    """The depth prior of the ``index``-th training view (near = bright), once computed."""
    if index >= job.n_train_views:
        raise ServiceError(
            404, "prior_not_found",
            f"job {job.id} has {job.n_train_views} training views: depth priors 0 to "
            f"{job.n_train_views - 1}",
        )  # fmt: skip
    try:
        path = service.storage.fetch(service.storage.prior_picture(job.id, index))
    except ArtifactMissing:
        raise ServiceError(
            404, "prior_not_found",
            f"no depth prior {index} for job {job.id} (none yet, or the job uses no prior)",
        ) from None  # fmt: skip
    return FileResponse(path, media_type="image/png")


_IMAGE_TYPES = {".png": "image/png", ".jpg": "image/jpeg", ".webp": "image/webp"}
