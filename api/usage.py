"""What one API key holds and may hold: the answer of ``GET /v1/usage``."""

from __future__ import annotations

from pydantic import BaseModel


class Usage(BaseModel):
    """One key's storage and jobs against its limits (a limit of None: none is set)."""

    owner: str
    """The key's id (the owner of its jobs; ``anonymous`` on a service without keys)."""
    stored_bytes: int
    """Bytes its jobs hold on disk now: uploads, checkpoints, models, exports, metrics (the
    sum of the files' sizes)."""
    stored_limit_bytes: int | None = None
    """Most bytes it may hold (``SPARSESPLAT_MAX_STORED_MB_PER_KEY``)."""
    jobs: int
    """Jobs it has stored, in any state."""
    jobs_limit: int | None = None
    """Most jobs it may keep stored (``SPARSESPLAT_MAX_JOBS_PER_KEY``)."""
    active_jobs: int
    """Its queued and running jobs."""
    active_jobs_limit: int
    """Most queued and running jobs at once (``SPARSESPLAT_MAX_ACTIVE_JOBS_PER_KEY``)."""
    models: int
    """Its models that can be rendered (succeeded, not expired)."""
    pinned_models: int
    """Of those, the ones kept past the expiry."""
    model_ttl_days: float | None = None
    """Days an unpinned model is kept after its job finished (None: for good)."""
