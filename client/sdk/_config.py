"""What a client is configured with: where the service is, named timeouts, the retry policy."""

from __future__ import annotations

import random
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any, Literal

from sparsesplat.api.jobs import Event

DEFAULT_URL = "http://127.0.0.1:8000"
"""Where the clients connect when no URL is given and ``SPARSESPLAT_URL`` is unset."""
URL_ENV = "SPARSESPLAT_URL"
"""Environment variable holding the service URL."""
API_KEY_ENV = "SPARSESPLAT_API_KEY"
"""Environment variable holding the API key."""

IdempotencyKey = str | Literal["auto"] | None
"""``"auto"``: a fresh random key per submission (retries reuse it); None: send none (and do
not retry the submission)."""
EventCallback = Callable[[Event], Any]
"""Called with each event ``wait()`` sees."""


@dataclass(frozen=True)
class Timeouts:
    """Named default timeouts in seconds (each call kind has its own)."""

    connect: float = 10.0
    """Establishing a connection (HTTP or WebSocket)."""
    read: float = 30.0
    """Ordinary API calls (job records, lists, cancel, delete)."""
    upload: float = 600.0
    """Submitting a job (the upload of every image)."""
    render: float = 120.0
    """One render; a camera path gets this per frame, up to ``download``."""
    download: float = 600.0
    """Downloading an export (.ply, .splat, checkpoint)."""
    event_idle: float = 60.0
    """Silence on an event stream before it is reconnected (the server polls every 0.25 s)."""


DEFAULT_TIMEOUTS = Timeouts()
"""The timeouts a client uses unless given others."""


@dataclass(frozen=True)
class RetryPolicy:
    """Retries with exponential backoff and jitter, for idempotent calls only (reads, cancel,
    delete, renders) and for submissions that carry an ``Idempotency-Key``.

    Retried: connection failures, timeouts, 502/503/504, and 429 when the server's
    ``Retry-After`` is at most ``max_backoff_s``."""

    max_retries: int = 3
    """Retries after the first attempt (0: never retry)."""
    backoff_s: float = 0.5
    """First delay; doubles each retry."""
    max_backoff_s: float = 10.0
    """Longest delay between two attempts."""
    retry_statuses: frozenset[int] = frozenset({429, 502, 503, 504})
    """HTTP statuses worth another try."""
    reconnect_s: float = 60.0
    """How long an event stream keeps trying to reconnect after losing the server."""

    def delay(self, attempt: int, retry_after: float | None = None) -> float:
        """Seconds to sleep before retry number ``attempt`` (1-based)."""
        if retry_after is not None:
            return min(max(retry_after, 0.0), self.max_backoff_s)
        base = min(self.backoff_s * 2.0 ** (attempt - 1), self.max_backoff_s)
        return base * (0.5 + random.random() / 2)


DEFAULT_RETRY = RetryPolicy()
"""The retry policy a client uses unless given another."""
