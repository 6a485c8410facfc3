"""Small response bodies shared by every route."""

from __future__ import annotations

from pydantic import BaseModel


class Health(BaseModel):
    """Answer of ``GET /healthz``: the process is up and serving."""

    status: str = "ok"
    """Always ``ok`` when the server answers."""
    version: str
    """sparsesplat version of the server."""
    queue: str
    """Configured queue backend."""
    device: str
    """Configured compute device."""
    kernels: str | None = None
    """The native CPU kernels' build on this machine: ``building``, ``ready`` or ``failed``;
    None when this server has no local build (GPU or remote workers)."""
    kernels_detail: str | None = None
    """One line on the build: seconds so far, the variants (AVX2/AVX-512) or the error."""
    disk: str = "ok"
    """The data folder's disk: ``ok``, ``low`` (under twice the reserve: the next jobs may
    wait for space) or ``full`` (under ``SPARSESPLAT_DISK_RESERVE_MB``: no job starts, uploads
    are refused with 507)."""
    disk_free_bytes: int | None = None
    """Bytes free on the data folder's disk."""


class ErrorBody(BaseModel):
    """Every 4xx/5xx answer: a machine-readable code and a sentence naming the problem."""

    code: str
    """Stable identifier of the error kind, e.g. ``invalid_cameras``."""
    message: str
    """What was wrong, naming the field or file."""


class Readiness(BaseModel):
    """Answer of ``GET /readyz`` (503 when not ready)."""

    ready: bool
    """Whether jobs submitted now will run and renders will be answered."""
    database: bool
    """Whether the job database answered."""
    workers: dict[str, int]
    """Workers with a fresh heartbeat, by kind (``train``, ``render``)."""
    problems: list[str]
    """What is missing, in words."""
