"""Fault injection for tests: a full disk at any write site, in the real service processes.

Off (nothing patched, nothing read) unless the environment variable
``SPARSESPLAT_TEST_FAULTS_FILE`` names a file; tests set it for the processes they start. Each
line of that file is one rule, and the file is read again whenever it changes, so a test can
fill the "disk" and free it again while the service runs:

- ``enospc PATTERN``: a file whose path matches ``PATTERN`` (``fnmatch`` on the whole path)
  opened for writing, or written by ``torch.save``, takes 4 KiB and then fails with ENOSPC,
  leaving the partial file behind as a full disk does;
- ``sqlite PATTERN``: an SQL statement matching ``PATTERN`` (``fnmatch``, e.g.
  ``UPDATE jobs*``) fails with SQLite's "database or disk is full";
- ``free BYTES``: the free space of the data folder reads as at most ``BYTES``.
"""

from __future__ import annotations

import builtins
import errno
import fnmatch
import io
import os
import sqlite3
from dataclasses import dataclass, field
from typing import Any

FAULTS_ENV = "SPARSESPLAT_TEST_FAULTS_FILE"
"""Environment variable naming the rules file (tests only)."""
PARTIAL_BYTES = 4096
"""Bytes a failing write keeps before it reports ENOSPC."""


@dataclass
class Rules:
    """The parsed rules file."""

    enospc: list[str] = field(default_factory=list)
    """Path patterns whose writes fail."""
    sqlite: list[str] = field(default_factory=list)
    """SQL patterns that fail as on a full database."""
    free: int | None = None
    """Free bytes to report, if limited."""


_cache: tuple[float, Rules] | None = None
_real_open = builtins.open


def rules() -> Rules:
    """The rules in force now (empty when fault injection is off or the file is absent)."""
    global _cache
    path = os.environ.get(FAULTS_ENV)
    if not path:
        return Rules()
    try:
        mtime = os.stat(path).st_mtime_ns
    except FileNotFoundError:
        return Rules()
    if _cache is None or _cache[0] != mtime:
        parsed = Rules()
        with _real_open(path, encoding="utf-8") as f:
            for line in f:
                kind, _, value = line.strip().partition(" ")
                if kind == "enospc":
                    parsed.enospc.append(value)
                elif kind == "sqlite":
                    parsed.sqlite.append(value)
                elif kind == "free":
                    parsed.free = int(value)
        _cache = (mtime, parsed)
    return _cache[1]


def fake_free_bytes() -> int | None:
    """The free space a ``free`` rule imposes, or None."""
    return rules().free if os.environ.get(FAULTS_ENV) else None


def _fails(path: Any) -> bool:
    if isinstance(path, int):
        return False
    text = os.fsdecode(os.fspath(path))
    return any(fnmatch.fnmatch(text, pattern) for pattern in rules().enospc)


def _enospc(path: Any) -> OSError:
    return OSError(errno.ENOSPC, os.strerror(errno.ENOSPC), os.fsdecode(os.fspath(path)))


class _FillingFile:
    """A file whose writes fail with ENOSPC once :data:`PARTIAL_BYTES` are written."""

    def __init__(self, real: Any, path: Any) -> None:
        self._real = real
        self._path = path
        self._room = PARTIAL_BYTES

    def write(self, data: Any) -> int:
        n = min(len(data), self._room)
        if n:
            self._real.write(data[:n])
            self._room -= n
        if n < len(data):
            raise _enospc(self._path)
        return n

    def writelines(self, lines: Any) -> None:
        for line in lines:
            self.write(line)

    def __enter__(self) -> _FillingFile:
        return self

    def __exit__(self, *exc: object) -> None:
        self._real.close()

    def __getattr__(self, name: str) -> Any:
        return getattr(self._real, name)


def _open(file: Any, mode: str = "r", *args: Any, **kwargs: Any) -> Any:
    real = _real_open(file, mode, *args, **kwargs)
    if any(c in mode for c in "wax+") and _fails(file):
        return _FillingFile(real, file)
    return real


def install(with_torch: bool = False) -> None:
    """Patch ``open`` (and ``torch.save`` with ``with_torch``) when fault injection is on."""
    if not os.environ.get(FAULTS_ENV):
        return
    builtins.open = _open
    io.open = _open  # pathlib opens through io.open
    if with_torch:
        import torch

        real_save = torch.save

        def save(obj: Any, f: Any, *args: Any, **kwargs: Any) -> None:
            if isinstance(f, str | os.PathLike) and _fails(f):
                with _real_open(f, "wb") as partial:
                    partial.write(b"\0" * PARTIAL_BYTES)
                raise _enospc(f)
            real_save(obj, f, *args, **kwargs)

        torch.save = save


def watch_engine(engine: Any) -> None:
    """Fail an SQLite engine's statements that match a ``sqlite`` rule (when injection is on)."""
    if not os.environ.get(FAULTS_ENV) or engine.dialect.name != "sqlite":
        return
    import sqlalchemy as sa

    @sa.event.listens_for(engine, "before_cursor_execute")
    def _maybe_full(conn: Any, cursor: Any, statement: str, params: Any, *_: Any) -> None:
        text = " ".join(statement.split())
        if any(fnmatch.fnmatch(text, pattern) for pattern in rules().sqlite):
            raise sa.exc.OperationalError(statement, params, sqlite3.OperationalError(SQLITE_FULL))


SQLITE_FULL = "database or disk is full"
"""What SQLite says when its file cannot grow."""
