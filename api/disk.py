"""Disk space under the data folder: what is free, what a folder holds, and telling a full disk
from other write failures.

Shared by the server (``/healthz``, uploads, usage) and the workers (the check before a job
starts, a write that fails mid-job). Imports neither FastAPI nor torch.
"""

from __future__ import annotations

import errno
import os
import shutil
from dataclasses import dataclass
from pathlib import Path

from sparsesplat.api import faults

DISK_FULL_ERRNOS = frozenset({errno.ENOSPC, errno.EDQUOT})
"""``errno`` values meaning "no room": the device is full, or a quota is."""
SQLITE_FULL = "database or disk is full"
"""SQLite's message for SQLITE_FULL (the database could not grow)."""
NO_SPACE = "No space left on device"
"""strerror(ENOSPC), as other layers quote it (PostgreSQL: ``could not extend file …: No space
left on device``)."""
PG_DISK_FULL = "53100"
"""PostgreSQL's SQLSTATE ``disk_full``."""
_TORCH_WRITER_FAILED = ("inline_container", "PytorchStreamWriter", "file write failed")
"""Words of the RuntimeError ``torch.save`` raises when a write fails: it carries no errno (on a
full disk it reads like ``[enforce fail at inline_container.cc:672] . unexpected pos 704 vs
598``), so a full disk is inferred from the free space left."""
PARTIAL_SUFFIX = ".tmp"
"""Files written under this suffix and renamed into place when complete."""


def free_bytes(path: str | Path) -> int:
    """Bytes an unprivileged writer may still use on the filesystem holding ``path``."""
    free = shutil.disk_usage(path).free
    fake = faults.fake_free_bytes()
    return free if fake is None else min(free, fake)


def disk_total_bytes(path: str | Path) -> int:
    """Size of the filesystem holding ``path``."""
    return shutil.disk_usage(path).total


def tree_bytes(path: str | Path) -> int:
    """Bytes of the regular files under ``path`` (0 when it does not exist); links are not
    followed, so a file counts once, under the job that holds it."""
    total = 0
    for folder, _dirs, files in os.walk(path):
        for name in files:
            try:
                total += os.lstat(os.path.join(folder, name)).st_size
            except FileNotFoundError:  # removed while we walked (a job finishing, a delete)
                continue
    return total


def mb(n_bytes: float) -> str:
    """``n_bytes`` in MB (10^6) for messages: ``44`` or ``0.3``."""
    value = n_bytes / 1e6
    return f"{value:.0f}" if value >= 10 else f"{value:.1f}"


def is_disk_full(exc: BaseException, free: int | None = None, needed: int | None = None) -> bool:
    """Whether ``exc`` (or an exception it was raised from) means the disk had no room.

    An ``OSError`` says so by its errno and SQLite by its message. ``torch.save`` says only that
    its write failed: that counts as a full disk when ``free`` (bytes free now) is below
    ``needed`` (what the file needs) or, with ``needed`` unknown, below 1 MB.
    """
    seen: set[int] = set()
    current: BaseException | None = exc
    while current is not None and id(current) not in seen:
        seen.add(id(current))
        if isinstance(current, OSError) and current.errno in DISK_FULL_ERRNOS:
            return True
        text = str(current)
        if SQLITE_FULL in text or NO_SPACE in text:
            return True
        if getattr(current, "sqlstate", None) == PG_DISK_FULL:
            return True
        writer_failed = isinstance(current, RuntimeError) and any(
            w in text for w in _TORCH_WRITER_FAILED
        )
        if writer_failed and free is not None and free < (needed or 1_000_000):
            return True
        current = current.__cause__ or current.__context__
    return False


def disk_full_message(site: str, needed: int | None, free: int) -> str:
    """The error a job or request gets: ``no space left on device while writing the training
    checkpoint (needs ~44 MB, 3 MB free)``."""
    need = f"needs ~{mb(needed)} MB, " if needed is not None else ""
    return f"no space left on device while {site} ({need}{mb(free)} MB free)"


def is_partial(path: Path) -> bool:
    """Whether ``path`` is a file being written: ``*.tmp``, or ``*.tmp.<ext>`` (NumPy adds its
    extension to the temporary name, as the depth-prior cache does)."""
    return path.suffix == PARTIAL_SUFFIX or PARTIAL_SUFFIX + "." in path.name


def remove_partial_files(folder: str | Path) -> list[Path]:
    """Remove every partial file (:func:`is_partial`) under ``folder`` (writes a failure left
    half done); returns what was removed."""
    removed = []
    for path in Path(folder).rglob("*" + PARTIAL_SUFFIX + "*"):
        if is_partial(path) and path.is_file():
            path.unlink(missing_ok=True)
            removed.append(path)
    return removed


@dataclass(frozen=True)
class DiskState:
    """Free space under the data folder and what it means for new work."""

    free_bytes: int
    """Bytes free."""
    total_bytes: int
    """Size of the filesystem."""
    status: str
    """``ok``; ``low`` (under twice the reserve: the next jobs may have to wait); ``full``
    (under the reserve: no job starts, uploads are refused)."""


def disk_state(path: str | Path, reserve_bytes: int) -> DiskState:
    """The :class:`DiskState` of the filesystem holding ``path``."""
    usage = shutil.disk_usage(path)
    free = free_bytes(path)
    status = "full" if free < reserve_bytes else "low" if free < 2 * reserve_bytes else "ok"
    return DiskState(free, usage.total, status)
