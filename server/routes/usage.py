"""``/v1/usage``: what the calling key stores and may store."""

from __future__ import annotations

from fastapi import APIRouter

from sparsesplat.api.usage import Usage
from sparsesplat.server.deps import OwnerDep, ServiceDep
from sparsesplat.server.storage_limits import key_usage

router = APIRouter(prefix="/v1/usage", tags=["usage"])


@router.get("", response_model=Usage, summary="Your key's storage and jobs against its limits")
def get_usage(service: ServiceDep, owner: OwnerDep) -> Usage:
    """Bytes your jobs hold on disk (measured from the files), your jobs and models, and the
    limits set on the service (null: none)."""
    return key_usage(service, owner)
