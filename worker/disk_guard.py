"""A full disk, on the worker's side: the check before a job starts, and turning a write that
failed mid-job into a failed job that names its cause and leaves no partial file.

The contract (``docs/service.md``, "Disk space"):

- before a job starts, its expected bytes (:mod:`sparsesplat.worker.disk_budget`) plus the
  reserve must be free; if not, it stays queued (the jobs behind it too: the queue keeps its
  order) and starts as soon as space returns, or fails after ``disk_wait_s`` naming what it
  needs and what is free;
- a write that fails mid-job for lack of space fails the job at once (retrying would redo the
  work into the same wall), naming the write and the space; its partial files, training
  checkpoint and exports are removed (a failed job cannot resume or be rendered), so the space
  goes back to the other jobs and the job database can store the outcome.
"""

from __future__ import annotations

import contextlib
import errno
import logging
import time
from typing import Any

from sparsesplat.api.disk import (
    disk_full_message,
    disk_total_bytes,
    free_bytes,
    is_disk_full,
    mb,
    remove_partial_files,
    tree_bytes,
)
from sparsesplat.api.jobs import JobSpec
from sparsesplat.api.settings import Settings
from sparsesplat.api.storage import Storage
from sparsesplat.api.store.jobs import JobStore
from sparsesplat.worker.disk_budget import (
    EXPORT_BYTES_PER_GAUSSIAN,
    expected_job_bytes,
    tensor_bytes,
)

log = logging.getLogger("sparsesplat.worker")

PHASE_SITES = {
    "preparing": "preparing the job's files",
    "depth prior": "writing the depth priors",
    "initializing": "writing the training metrics",
    "training": "writing the training metrics",
    "evaluating": "writing the training metrics",
    "checkpointing": "writing the training checkpoint",
    "storing": "saving the final model",
}
"""What the job writes in each phase, for the error of a write that failed then."""
WRITE_ERRNOS = frozenset({errno.EROFS, errno.EIO})
"""Other errors of a write that fail the job the same way (a read-only or failing disk)."""
EXPORT_SITE = "writing the exports (model.ply, model.splat)"
DATABASE_SITE = "committing to the job database"
DEAD_WEIGHT = ("checkpoint", "ply", "splat")
"""Artifacts a failed job does not need (it cannot resume or be rendered): removed when a full
disk failed it, so the space goes back to the others."""


class WriteSites:
    """Follows what a running job writes, to name the write that failed and what it needed."""

    def __init__(self, storage: Storage, job_id: str) -> None:
        """For ``job_id`` in ``storage``."""
        self.storage = storage
        self.job_id = job_id
        self.phase = "preparing"
        self.free_at_start = free_bytes(storage.root)

    def enter(self, phase: str) -> None:
        """The job moves to ``phase``: note the free space as it starts writing there."""
        self.phase = phase
        with contextlib.suppress(OSError):  # a statvfs failing is no reason to fail the job
            self.free_at_start = free_bytes(self.storage.root)

    def failure(self, exc: BaseException, trainer: Any) -> str | None:
        """The job's error if ``exc`` is a write that failed (a full disk, or another error of
        the filesystem), after removing what the failure left; None for any other error."""
        site, needed = self._site(exc, trainer)
        free_now = free_bytes(self.storage.root)
        full = is_disk_full(exc, free_now, needed)
        if not full and not (isinstance(exc, OSError) and exc.errno in WRITE_ERRNOS):
            return None
        self.clean_up(dead_weight=full)
        if full:  # the space there was when the write began: now it is all taken
            return disk_full_message(site, needed, self.free_at_start)
        return f"could not write to the data folder while {site}: {exc}"

    def clean_up(self, dead_weight: bool) -> None:
        """Remove partial files and, with ``dead_weight``, the checkpoint and the exports."""
        run_dir = self.storage.run_dir(self.job_id)
        removed = [str(p.name) for p in remove_partial_files(self.storage.job_dir(self.job_id))]
        if dead_weight:
            for kind in DEAD_WEIGHT:
                path = self.storage.artifact(self.job_id, kind)
                if path.is_file():
                    path.unlink()
                    removed.append(path.name)
        if removed:
            log.info("removed after a failed write", extra={"files": removed,
                                                            "run_dir": str(run_dir)})  # fmt: skip

    def _site(self, exc: BaseException, trainer: Any) -> tuple[str, int | None]:
        """(what was being written, the bytes it needed when known)."""
        import sqlalchemy as sa

        if isinstance(exc, sa.exc.OperationalError):
            return DATABASE_SITE, None
        site = PHASE_SITES.get(self.phase, "writing the job's files")
        if self.phase == "checkpointing":
            tmp = self.storage.artifact(self.job_id, "checkpoint").with_suffix(".pt.tmp")
            if not tmp.exists():  # the checkpoint was written; the exports come next
                return EXPORT_SITE, _export_bytes(trainer)
            return site, _state_bytes(trainer, model_only=False)
        if self.phase == "storing":
            return site, _state_bytes(trainer, model_only=True)
        return site, None


def _state_bytes(trainer: Any, model_only: bool) -> int | None:
    """Bytes of the checkpoint ``trainer`` writes (the finished model's with ``model_only``)."""
    if trainer is None:
        return None
    from sparsesplat.engine.model.checkpoint import model_state

    try:
        state = trainer.state_dict()
        return tensor_bytes(model_state(state) if model_only else state)
    except Exception:  # a size for the message is not worth a second failure
        return None


def _export_bytes(trainer: Any) -> int | None:
    return None if trainer is None else EXPORT_BYTES_PER_GAUSSIAN * len(trainer.gaussians)


EXPECTED_CACHE = 1000
"""Jobs whose expected bytes a gate remembers (then it forgets them all and starts again)."""


class DiskGate:
    """Lets a queued job start only when its expected bytes fit (see the module's contract)."""

    def __init__(self, store: JobStore, storage: Storage, settings: Settings) -> None:
        """The gate for jobs of ``store`` whose files live in ``storage``."""
        self.store = store
        self.storage = storage
        self.settings = settings
        self._expected: dict[str, int] = {}

    def expected_bytes(self, job_id: str, spec: dict[str, Any]) -> int:
        """The job's expected bytes (computed once per job)."""
        if len(self._expected) > EXPECTED_CACHE:
            self._expected.clear()
        if job_id not in self._expected:
            try:
                job_spec = JobSpec.model_validate(spec)
                self.storage.fetch_upload(job_id)  # from the artifact store, when one is set
                self._expected[job_id] = expected_job_bytes(
                    job_spec, self.storage.upload_dir(job_id)
                )
            except Exception:  # never block the queue on an estimate: the job reports errors
                log.warning("no disk estimate for the job", exc_info=True,
                            extra={"job_id": job_id})  # fmt: skip
                self._expected[job_id] = 0
        return self._expected[job_id]

    def may_start(self, job_id: str, spec: dict[str, Any], waiting_since: float | None) -> bool:
        """Whether ``job_id`` (queued) fits now. When it does not, it is marked as waiting
        (once) or, after ``disk_wait_s`` of waiting, failed; either way False."""
        reserve = self.settings.disk_reserve_mb * 1_000_000
        needed = self._still_to_write(job_id, spec)
        # Jobs running beside it (other workers) will still grow: their room is taken.
        promised = sum(self._still_to_write(i, s) for i, s in self.store.running_specs())
        free = max(free_bytes(self.storage.root) - promised, 0)
        if free >= needed + reserve:
            return True
        total = disk_total_bytes(self.storage.root)
        if needed + reserve > total:  # it never will fit: waiting would only hold the queue
            message = (
                f"no space left on device to start this job (needs ~{mb(needed)} MB plus the "
                f"{mb(reserve)} MB reserve; the data folder's disk holds {mb(total)} MB in all)"
            )
            if self.store.fail_queued(job_id, message):
                log.error("job failed: it cannot fit on the disk", extra={"job_id": job_id})
            return False
        wait = self.settings.disk_wait_s
        if waiting_since is None:
            message = (
                f"waiting for disk space: this job needs ~{mb(needed)} MB and the service keeps "
                f"{mb(reserve)} MB free (SPARSESPLAT_DISK_RESERVE_MB); {mb(free)} MB are free. "
                f"It starts when space returns, or fails after {wait:g} s"
            )
            log.warning("job waits for disk space", extra={"job_id": job_id, "needed": needed,
                                                           "free": free})  # fmt: skip
            waiting_since = self.store.note_disk_wait(job_id, message)
        if waiting_since is not None and time.time() - waiting_since >= wait:
            message = (
                f"no space left on device to start this job (needs ~{mb(needed)} MB plus the "
                f"{mb(reserve)} MB reserve, {mb(free)} MB free; waited {wait:g} s for space, "
                "SPARSESPLAT_DISK_WAIT_S)"
            )
            if self.store.fail_queued(job_id, message):
                log.error("job failed: no disk space to start", extra={"job_id": job_id})
        return False

    def _still_to_write(self, job_id: str, spec: dict[str, Any]) -> int:
        """Expected bytes of the job less what its run folder holds already (a job resumed
        after its worker died has its checkpoint on disk)."""
        return max(self.expected_bytes(job_id, spec) - tree_bytes(self.storage.run_dir(job_id)), 0)
