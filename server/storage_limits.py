"""What a key stores against its limits, and the free space an upload needs.

Usage is measured, not counted: the bytes of the files under the key's job folders (or its
jobs' objects in the bucket, with a remote artifact store), so the figures equal what is
stored (a running job's checkpoint included).
"""

from __future__ import annotations

from sparsesplat.api.disk import disk_full_message, free_bytes, mb
from sparsesplat.api.usage import Usage
from sparsesplat.server.errors import ServiceError
from sparsesplat.server.state import ServiceState


def key_usage(service: ServiceState, owner: str) -> Usage:
    """``owner``'s usage and limits (walks its job folders: call off the event loop)."""
    settings = service.settings
    stored = sum(service.storage.job_bytes(i) for i in service.jobs.ids_of_owner(owner))
    counts = service.jobs.counts_of_owner(owner)
    return Usage(
        owner=owner,
        stored_bytes=stored,
        stored_limit_bytes=settings.max_stored_mb_per_key * 1_000_000 or None,
        jobs=counts["jobs"],
        jobs_limit=settings.max_jobs_per_key or None,
        active_jobs=counts["active"],
        active_jobs_limit=settings.max_active_jobs_per_key,
        models=counts["models"],
        pinned_models=counts["pinned"],
        model_ttl_days=settings.model_ttl_days or None,
    )


def check_submission(service: ServiceState, owner: str, upload_bytes: int) -> None:
    """Refuse a new job of ``upload_bytes`` when the key is at a limit (429 for its number of
    jobs, 413 for its bytes) or the disk has no room for the upload (507). Nothing is read or
    stored before this passes."""
    settings = service.settings
    if settings.max_jobs_per_key or settings.max_stored_mb_per_key:
        usage = key_usage(service, owner)
        if usage.jobs_limit is not None and usage.jobs >= usage.jobs_limit:
            raise ServiceError(
                429, "too_many_stored_jobs",
                f"key {owner} stores {usage.jobs} jobs of its {usage.jobs_limit} limit "
                "(SPARSESPLAT_MAX_JOBS_PER_KEY): delete some (DELETE /v1/jobs/ID)",
            )  # fmt: skip
        limit = usage.stored_limit_bytes
        if limit is not None and usage.stored_bytes + upload_bytes > limit:
            adds = f"; this upload adds {mb(upload_bytes)} MB" if upload_bytes else ""
            raise ServiceError(
                413, "storage_limit",
                f"key {owner} stores {mb(usage.stored_bytes)} MB of its {mb(limit)} MB limit"
                f"{adds} (SPARSESPLAT_MAX_STORED_MB_PER_KEY): delete jobs "
                "(DELETE /v1/jobs/ID) to make room",
            )  # fmt: skip
    check_free_space(service, upload_bytes, "receiving the upload")


def check_free_space(service: ServiceState, needed: int, site: str) -> None:
    """507 when ``needed`` bytes would take the disk under the reserve."""
    reserve = service.settings.disk_reserve_mb * 1_000_000
    free = free_bytes(service.storage.root)
    if free < needed + reserve:
        raise ServiceError(
            507, "insufficient_storage",
            disk_full_message(site, needed, free)
            + f"; the service keeps {mb(reserve)} MB free (SPARSESPLAT_DISK_RESERVE_MB)",
            {"Retry-After": "60"},
        )  # fmt: skip


def declared_length(headers: dict[str, str]) -> int:
    """The request's Content-Length (0 when absent or not a number)."""
    value = headers.get("content-length", "")
    return int(value) if value.isdigit() else 0
