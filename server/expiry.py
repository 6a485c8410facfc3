"""Model expiry and stray files: what the server removes by itself, and the 404 of a model
that expired.

A succeeded job's model is kept ``model_ttl_days`` after the job finished unless pinned; then
its files are removed (the record stays, answering ``expired``). Files of a job whose record
is gone (a worker that finished writing after a DELETE) are removed too.
"""

from __future__ import annotations

import asyncio
import logging
import time
from datetime import UTC, datetime

from sparsesplat.api.jobs import Job
from sparsesplat.server.errors import ServiceError
from sparsesplat.server.state import ServiceState

log = logging.getLogger("sparsesplat.server")

STRAY_AGE_S = 600.0
"""A job folder without a record is removed once this old (an upload is stored a moment
before its record: younger folders may be jobs being submitted)."""


def expired_error(service: ServiceState, job: Job) -> ServiceError:
    """404 ``model_expired`` for ``job``'s expired model, saying when and why."""
    days = service.settings.model_ttl_days
    when = ""
    if job.finished_at is not None and days > 0:
        moment = job.finished_at.timestamp() + days * 86400
        when = f" on {datetime.fromtimestamp(moment, UTC):%Y-%m-%d %H:%M} UTC"
    return ServiceError(
        404, "model_expired",
        f"model {job.id} expired{when}: models are kept {days:g} days after training unless "
        "pinned (SPARSESPLAT_MODEL_TTL_DAYS); its files are gone",
    )  # fmt: skip


def sweep(service: ServiceState) -> list[str]:
    """Remove the files of expired models and of job folders without a record; returns the
    job ids whose files went."""
    removed = []
    for job_id in service.jobs.expired_unswept():
        if service.jobs.mark_expired(job_id):  # a pin may win the race: then it stays
            service.storage.delete_job(job_id)
            removed.append(job_id)
    known = service.jobs.all_ids()
    now = time.time()
    # Here and, with an artifact store, in the bucket (a worker killed after its job was
    # deleted leaves objects no machine has a folder for).
    for job_id, changed_at in service.storage.stored_jobs().items():
        if job_id not in known and now - changed_at > STRAY_AGE_S:
            service.storage.delete_job(job_id)
            removed.append(job_id)
    if removed:
        log.info("swept expired models and stray files", extra={"jobs": removed})
    return removed


def expire_now(service: ServiceState, job_id: str) -> None:
    """Remove an expired model's files at once (a request found it past its time)."""
    if service.jobs.mark_expired(job_id):
        service.storage.delete_job(job_id)


async def sweep_forever(service: ServiceState) -> None:
    """:func:`sweep` every ``sweep_interval_s`` until cancelled (errors are logged, never
    fatal)."""
    while True:
        try:
            await asyncio.to_thread(sweep, service)
        except Exception:
            log.warning("sweep failed", exc_info=True)
        await asyncio.sleep(service.settings.sweep_interval_s)
