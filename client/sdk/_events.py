"""Where an event stream stands, without any I/O: the last sequence number seen, the caller's
deadline, how long the server has been gone, the reconnect backoff.

Both clients' ``events()`` drive one :class:`EventCursor` around their own WebSocket (sync or
asyncio); every decision (drop a repeat, stop at the terminal state, give up, reconnect, which
error a close code means) is made here once.
"""

from __future__ import annotations

import time
from typing import Any

from sparsesplat.api.jobs import Event
from sparsesplat.api.names import TERMINAL_JOB_STATES
from sparsesplat.client.errors import (
    APIError,
    AuthenticationError,
    ConnectionFailed,
    NotFound,
    ServerError,
    Timeout,
)
from sparsesplat.client.sdk._config import RetryPolicy


class EventCursor:
    """Resume bookkeeping of one job's event stream.

    Args:
        job_id: the job whose events are read.
        after: events with ``seq <= after`` are skipped (0: from the start).
        timeout: seconds until the stream must have ended (None: no limit).
        idle_s: silence after which the connection is reopened.
        retry: the client's policy (``reconnect_s``, backoff delays).
    """

    def __init__(
        self, job_id: str, after: int, timeout: float | None, idle_s: float, retry: RetryPolicy
    ) -> None:
        self.job_id = job_id
        self.last = after
        """Sequence number of the last event handed out (the ``?after=`` of a reconnect)."""
        self.ended = False
        """Whether the last event handed out was the job's terminal state."""
        self._timeout = timeout
        self._deadline = None if timeout is None else time.monotonic() + timeout
        self._idle_s = idle_s
        self._retry = retry
        self._lost_since: float | None = None
        self._attempt = 0

    def connected(self) -> None:
        """A connection is open: the reconnect clock and backoff start afresh."""
        self._lost_since, self._attempt = None, 0

    def _timed_out(self) -> Timeout:
        return Timeout(f"job {self.job_id}: no end within {self._timeout} s")

    def recv_timeout(self) -> float:
        """Seconds to wait for the next message (Timeout when the deadline has passed)."""
        wait = self._idle_s
        if self._deadline is not None:
            wait = min(wait, self._deadline - time.monotonic())
            if wait <= 0:
                raise self._timed_out()
        return wait

    def idle(self) -> None:
        """Nothing arrived within :meth:`recv_timeout`: Timeout past the deadline, else the
        caller reconnects."""
        if self._deadline is not None and time.monotonic() >= self._deadline:
            raise self._timed_out() from None

    def accept(self, message: str | bytes) -> Event | None:
        """The event of ``message``, or None when it was already handed out (a replay after
        a reconnect)."""
        event = Event.model_validate_json(message)
        if event.seq <= self.last:
            return None
        self.last = event.seq
        self.ended = event.type == "state" and event.data.get("state") in TERMINAL_JOB_STATES
        return event

    def closed(self, frame: Any) -> bool:
        """The server closed the stream with close ``frame`` (None if none came): raise the
        error its code stands for; True when it was a normal close (1000), after which the
        caller asks whether the job has ended; False: reconnect."""
        code = frame.code if frame is not None else None
        reason = frame.reason if frame is not None else ""
        if code == 4404:
            raise NotFound(404, "job_not_found", reason or f"no job {self.job_id!r}")
        if code == 4401:
            raise AuthenticationError(
                401, "unauthenticated", reason or "missing or unknown API key"
            )
        return code == 1000

    @staticmethod
    def refused(status: int, exc: Exception) -> APIError:
        """The error for a handshake the server refused with HTTP ``status``."""
        return ServerError(status, "events_refused", f"event stream refused: {exc}")

    def lost(self, exc: Exception, base_url: str) -> None:
        """The connection failed: ConnectionFailed once the server has been gone longer than
        ``retry.reconnect_s``."""
        self._lost_since = self._lost_since or time.monotonic()
        if time.monotonic() - self._lost_since > self._retry.reconnect_s:
            raise ConnectionFailed(
                f"lost the event stream of job {self.job_id} at {base_url}: {exc}"
            ) from exc

    def backoff(self) -> float:
        """Seconds to sleep before the next connection attempt."""
        self._attempt += 1
        return self._retry.delay(min(self._attempt, 5))
