"""The event stream's resume bookkeeping (no I/O), which both clients' ``events()`` share."""

from __future__ import annotations

import json
from types import SimpleNamespace

import pytest

from sparsesplat.client import ConnectionFailed, NotFound, RetryPolicy, Timeout
from sparsesplat.client.errors import AuthenticationError
from sparsesplat.client.sdk._events import EventCursor


def _message(seq: int, kind: str = "progress", **data: object) -> str:
    return json.dumps(
        {"seq": seq, "job_id": "job_x", "time": "2026-01-01T00:00:00Z", "type": kind, "data": data}
    )


def _cursor(after: int = 0, timeout: float | None = None, reconnect_s: float = 60.0) -> EventCursor:
    return EventCursor("job_x", after, timeout, 30.0, RetryPolicy(reconnect_s=reconnect_s))


def test_replayed_events_are_dropped_and_the_resume_point_advances() -> None:
    cursor = _cursor(after=2)
    assert cursor.accept(_message(1)) is None and cursor.accept(_message(2)) is None
    event = cursor.accept(_message(3))
    assert event is not None and event.seq == 3 and cursor.last == 3
    # After a reconnect with ?after=3 the server may resend 3: it is not handed out twice.
    assert cursor.accept(_message(3)) is None
    assert not cursor.ended


@pytest.mark.parametrize("state", ["succeeded", "failed", "cancelled"])
def test_a_terminal_state_ends_the_stream(state: str) -> None:
    cursor = _cursor()
    cursor.accept(_message(1, "state", state="running"))
    assert not cursor.ended
    cursor.accept(_message(2, "state", state=state))
    assert cursor.ended


def test_close_codes() -> None:
    cursor = _cursor()
    with pytest.raises(NotFound):
        cursor.closed(SimpleNamespace(code=4404, reason=""))
    with pytest.raises(AuthenticationError):
        cursor.closed(SimpleNamespace(code=4401, reason="bad key"))
    assert cursor.closed(SimpleNamespace(code=1000, reason="")) is True
    assert cursor.closed(SimpleNamespace(code=1011, reason="")) is False
    assert cursor.closed(None) is False


def test_a_passed_deadline_is_a_timeout() -> None:
    cursor = _cursor(timeout=30.0)
    assert 0 < cursor.recv_timeout() <= 30.0
    cursor.idle()  # before the deadline: only a reconnect
    expired = _cursor(timeout=1e-9)
    with pytest.raises(Timeout):
        expired.recv_timeout()
    with pytest.raises(Timeout):
        expired.idle()


def test_losing_the_server_longer_than_reconnect_s_gives_up() -> None:
    patient = _cursor(reconnect_s=60.0)
    patient.lost(OSError("refused"), "http://h")  # first loss: keep trying
    hopeless = _cursor(reconnect_s=-1.0)
    with pytest.raises(ConnectionFailed, match="lost the event stream of job job_x"):
        hopeless.lost(OSError("refused"), "http://h")
    # A successful connection resets the clock and the backoff.
    patient.backoff()
    patient.connected()
    assert patient.backoff() <= RetryPolicy().backoff_s
