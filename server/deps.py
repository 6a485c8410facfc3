"""Typed dependencies (what a route may ask for by annotation) and the checks that routes of
more than one router share."""

from __future__ import annotations

from typing import Annotated

from fastapi import Depends, Header, Request

from sparsesplat.api.jobs import Job, JobState
from sparsesplat.api.renders import RenderRequest
from sparsesplat.server.auth import Authenticator, Unauthenticated
from sparsesplat.server.errors import ServiceError, not_found
from sparsesplat.server.expiry import expire_now, expired_error
from sparsesplat.server.state import ServiceState


def get_service(request: Request) -> ServiceState:
    """The application's :class:`ServiceState`."""
    service: ServiceState = request.app.state.service
    return service


ServiceDep = Annotated[ServiceState, Depends(get_service)]


def get_owner(request: Request, authorization: Annotated[str | None, Header()] = None) -> str:
    """The caller's owner id (401 without a valid key when keys are configured)."""
    authenticator: Authenticator = request.app.state.authenticator
    try:
        return authenticator.owner(authorization)
    except Unauthenticated as exc:
        raise ServiceError(
            401, "unauthenticated", str(exc), {"WWW-Authenticate": "Bearer"}
        ) from exc


OwnerDep = Annotated[str, Depends(get_owner)]


def get_own_job(job_id: str, service: ServiceDep, owner: OwnerDep) -> Job:
    """The caller's job ``job_id`` (404 when missing or another key's: never 403)."""
    job = service.jobs.get(job_id, owner)
    if job is None:
        raise not_found("job", job_id)
    return job


OwnJobDep = Annotated[Job, Depends(get_own_job)]


def own_model(service: ServiceState, owner: str, model_id: str) -> Job:
    """The succeeded job of ``model_id`` if ``owner`` may use it; ServiceError 404 / 409."""
    job = service.jobs.get(model_id, owner)
    if job is None:
        raise not_found("model", model_id)
    if job.expired:
        expire_now(service, model_id)  # past its time but not swept yet: its bytes go now
        raise expired_error(service, job)
    if job.state != JobState.succeeded:
        raise ServiceError(
            409,
            "model_not_ready",
            f"job {model_id} is {job.state.value}: a model exists once the job has succeeded",
        )
    return job


def check_render_size(service: ServiceState, request: RenderRequest) -> None:
    """ServiceError 413 when the request asks for more cameras or pixels than allowed."""
    settings = service.settings
    if request.path is not None and len(request.path) > settings.max_path_cameras:
        raise ServiceError(
            413, "path_too_long",
            f"{len(request.path)} cameras; the limit is {settings.max_path_cameras} "
            "(SPARSESPLAT_MAX_PATH_CAMERAS)",
        )  # fmt: skip
    for camera in request.cameras:
        megapixels = (
            (camera.width // request.downscale) * (camera.height // request.downscale) / 1e6
        )
        if megapixels > settings.max_render_megapixels:
            raise ServiceError(
                413, "render_too_large",
                f"{camera.width}x{camera.height} / {request.downscale} is {megapixels:.1f} "
                f"megapixels; the limit is {settings.max_render_megapixels:g} "
                "(SPARSESPLAT_MAX_RENDER_MEGAPIXELS): ask for a downscale",
            )  # fmt: skip
