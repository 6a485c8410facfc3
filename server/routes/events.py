"""``/v1/jobs/{id}/events``: a job's stored events over a WebSocket, then live ones.

A client that reconnects with ``?after=N`` (the last ``seq`` it saw) gets exactly the events it
missed, then the new ones as they are stored: no gap, no duplicate. Events are read from the
database, so they survive a server restart and reach every API process alike.
"""

from __future__ import annotations

import asyncio
from typing import Annotated

from fastapi import APIRouter, Query, WebSocket, WebSocketDisconnect

from sparsesplat.server.auth import Authenticator, Unauthenticated
from sparsesplat.server.errors import CLOSE_NOT_FOUND, CLOSE_UNAUTHENTICATED
from sparsesplat.server.state import ServiceState

router = APIRouter(prefix="/v1/jobs", tags=["events"])

POLL_S = 0.25
"""How often a live stream looks for new events."""


@router.websocket("/{job_id}/events")
async def job_events(
    websocket: WebSocket,
    job_id: str,
    after: Annotated[int, Query(ge=0)] = 0,
    access_token: str | None = None,
) -> None:
    """Stream events with ``seq > after`` as JSON text frames; closes after the terminal
    state's event. Browsers, which cannot set headers on a WebSocket, pass the API key as
    ``access_token``."""
    service: ServiceState = websocket.app.state.service
    authenticator: Authenticator = websocket.app.state.authenticator
    header = websocket.headers.get("authorization")
    if header is None and access_token:
        header = f"Bearer {access_token}"
    # Accept before refusing: a close before the handshake reaches clients as a bare HTTP 403,
    # and the close code (which says why) would be lost.
    await websocket.accept()
    try:
        owner = await asyncio.to_thread(authenticator.owner, header)
    except Unauthenticated as exc:
        await websocket.close(code=CLOSE_UNAUTHENTICATED, reason=str(exc)[:120])
        return
    job = await asyncio.to_thread(service.jobs.get, job_id, owner)
    if job is None:
        await websocket.close(code=CLOSE_NOT_FOUND, reason=f"no job {job_id!r}")
        return
    # The client never sends anything; reading anyway is how a dropped connection is noticed
    # on a quiet job (otherwise the stream would poll the database until the job ends).
    gone = asyncio.create_task(_until_disconnect(websocket))
    try:
        await _stream(websocket, service, job_id, owner, after, gone)
    finally:
        gone.cancel()


async def _until_disconnect(websocket: WebSocket) -> None:
    while True:
        message = await websocket.receive()
        if message["type"] == "websocket.disconnect":
            return


async def _stream(
    websocket: WebSocket,
    service: ServiceState,
    job_id: str,
    owner: str,
    after: int,
    gone: asyncio.Task[None],
) -> None:
    last = after
    try:
        while not gone.done():
            events = await asyncio.to_thread(service.jobs.events_after, job_id, last)
            for event in events:
                await websocket.send_text(event.model_dump_json())
                last = event.seq
                if event.type == "state" and event.data.get("state") in (
                    "succeeded", "failed", "cancelled",
                ):  # fmt: skip
                    await websocket.close()
                    return
            if not events:
                current = await asyncio.to_thread(service.jobs.get, job_id, owner)
                if current is None:
                    await websocket.close(code=CLOSE_NOT_FOUND, reason="job deleted")
                    return
                if (
                    current.state.terminal
                    and await asyncio.to_thread(service.jobs.last_seq, job_id) <= last
                ):
                    await websocket.close()
                    return
                await asyncio.wait([gone], timeout=POLL_S)
    except WebSocketDisconnect:
        return
