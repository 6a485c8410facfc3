"""Typed dependencies: what a route may ask for by annotation."""

from __future__ import annotations

from typing import Annotated

from fastapi import Depends, Header, Request

from sparsesplat.api.jobs import Job
from sparsesplat.server.auth import Authenticator, Unauthenticated
from sparsesplat.server.errors import ServiceError, not_found
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
