"""The state of the native CPU kernels' build, as a small JSON file a server can read.

The kernels (rasterizer, projection, hash grid, photometric loss) compile once after install or
update, which takes minutes on 2 cores. ``sparsesplat serve`` builds them before its workers
start taking jobs (``sparsesplat build`` writes this file as it goes), and ``/healthz`` and
``/readyz`` read it, so an operator sees "building" instead of a service that silently takes
jobs it cannot start. Pure Python: the API process reads it without importing torch.
"""

from __future__ import annotations

import json
import os
import time
from enum import StrEnum
from pathlib import Path

from pydantic import BaseModel, ValidationError

STATUS_FILE = "kernels.json"
"""Name of the status file in the service's data folder."""


class KernelState(StrEnum):
    """Where the build stands."""

    building = "building"
    ready = "ready"
    failed = "failed"


class KernelStatus(BaseModel):
    """Contents of the status file."""

    state: KernelState
    """building, ready or failed."""
    started_at: float
    """Unix time the build (or load) started."""
    finished_at: float | None = None
    """Unix time it ended; None while building."""
    pid: int
    """Process doing the build: a "building" file whose process is gone means it was killed."""
    variants: dict[str, str] = {}
    """Extension -> instruction-set variant (e.g. ``{"CPU rasterizer": "avx512"}``), when ready."""
    message: str = ""
    """Why the build failed (the compiler's last lines), empty otherwise."""

    def summary(self, now: float | None = None) -> str:
        """One line for logs and health answers."""
        now = time.time() if now is None else now
        if self.state == KernelState.building:
            return f"building the native CPU kernels ({now - self.started_at:.0f} s so far)"
        if self.state == KernelState.failed:
            return f"building the native CPU kernels failed: {self.message[-300:]}"
        return "native CPU kernels ready: " + ", ".join(
            f"{name} {isa}" for name, isa in sorted(self.variants.items())
        )


def write_status(path: Path, status: KernelStatus) -> None:
    """Replace the file atomically (readers never see half of it)."""
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(f".{path.name}.{os.getpid()}.tmp")
    tmp.write_text(status.model_dump_json())
    os.replace(tmp, path)


def _alive(pid: int) -> bool:
    """Whether a process with this id exists on this machine."""
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        return True
    return True


def read_status(path: Path) -> KernelStatus | None:
    """The status in ``path``, None when there is none (no local build: e.g. a GPU or Celery
    deployment whose workers run elsewhere). A "building" file whose process died reads as
    failed, so a killed build does not look like one that is still going."""
    try:
        status = KernelStatus.model_validate(json.loads(path.read_text()))
    except (OSError, ValueError, ValidationError):
        return None
    if status.state == KernelState.building and not _alive(status.pid):
        return status.model_copy(
            update={"state": KernelState.failed, "message": "the build process exited early"}
        )
    return status
