"""``/v1/models/{id}/live``: a live view over a WebSocket — camera poses in, renders out.

The page sends a :class:`~sparsesplat.api.renders.LivePose` as a text message whenever its
camera moves; the server renders one pose at a time per connection and answers each with one
binary message (a :class:`~sparsesplat.api.renders.LiveFrame` header, then the image). A pose
that arrives while a render runs replaces the one waiting, if any (latest pose wins): the view
follows the camera and a frame is never older than about two renders, however fast the camera
moves. Invalid poses are answered with a text message ``{"type": "error", ...}`` and the
connection stays open; a missing key, model or render worker closes it with a code.
"""

from __future__ import annotations

import asyncio
import json
import time

from fastapi import APIRouter, WebSocket, WebSocketDisconnect
from pydantic import ValidationError

from sparsesplat.api.renders import MEDIA_TYPES, LiveFrame, LivePose, pack_live_frame
from sparsesplat.server.auth import Authenticator, Unauthenticated
from sparsesplat.server.deps import check_render_size, own_model
from sparsesplat.server.errors import (
    CLOSE_NOT_FOUND,
    CLOSE_UNAUTHENTICATED,
    ServiceError,
    pydantic_message,
)
from sparsesplat.server.render_dispatch import NoRenderWorker, RenderFailed
from sparsesplat.server.state import ServiceState

router = APIRouter(prefix="/v1/models", tags=["models"])

CLOSE_NOT_READY = 4409
"""WebSocket close code: the job has no model (yet)."""
CLOSE_NO_RENDER_WORKER = 4503
"""WebSocket close code: no render worker is running."""


class _LatestPose:
    """The pose waiting to be rendered; a newer one replaces it (counted as dropped)."""

    def __init__(self) -> None:
        self.pose: LivePose | None = None
        self.dropped = 0
        self.ready = asyncio.Event()

    def put(self, pose: LivePose) -> None:
        if self.pose is not None:
            self.dropped += 1
        self.pose = pose
        self.ready.set()

    def take(self) -> LivePose | None:
        pose, self.pose = self.pose, None
        self.ready.clear()
        return pose


@router.websocket("/{model_id}/live")
async def live_view(websocket: WebSocket, model_id: str, access_token: str | None = None) -> None:
    """Render each latest pose the client sends and send the frames back (see the module
    docstring). Browsers pass the API key as ``access_token``."""
    service: ServiceState = websocket.app.state.service
    authenticator: Authenticator = websocket.app.state.authenticator
    header = websocket.headers.get("authorization")
    if header is None and access_token:
        header = f"Bearer {access_token}"
    await websocket.accept()  # before refusing, so that the close code reaches the client
    try:
        owner = await asyncio.to_thread(authenticator.owner, header)
        await asyncio.to_thread(own_model, service, owner, model_id)
    except Unauthenticated as exc:
        await websocket.close(code=CLOSE_UNAUTHENTICATED, reason=str(exc)[:120])
        return
    except ServiceError as exc:
        code = CLOSE_NOT_FOUND if exc.status_code == 404 else CLOSE_NOT_READY
        await websocket.close(code=code, reason=str(exc.detail)[:120])
        return
    latest = _LatestPose()
    reader = asyncio.create_task(_read_poses(websocket, service, latest))
    try:
        await _render_loop(websocket, service, owner, model_id, latest, reader)
    except WebSocketDisconnect:
        return
    finally:
        reader.cancel()


async def _read_poses(websocket: WebSocket, service: ServiceState, latest: _LatestPose) -> None:
    """Receive poses until the client goes; invalid ones are answered with an error message."""
    while True:
        message = await websocket.receive()
        if message["type"] == "websocket.disconnect":
            return
        text = message.get("text")
        if text is None:
            await _send_error(websocket, "invalid_pose", "send poses as JSON text messages")
            continue
        try:
            pose = LivePose.model_validate_json(text)
            check_render_size(service, pose.render_request())
        except ValidationError as exc:
            await _send_error(websocket, "invalid_pose", pydantic_message(exc, "pose"))
            continue
        except ServiceError as exc:
            await _send_error(websocket, exc.code, str(exc.detail))
            continue
        latest.put(pose)


async def _send_error(websocket: WebSocket, code: str, message: str) -> None:
    await websocket.send_text(json.dumps({"type": "error", "code": code, "message": message}))


async def _render_loop(
    websocket: WebSocket,
    service: ServiceState,
    owner: str,
    model_id: str,
    latest: _LatestPose,
    reader: asyncio.Task[None],
) -> None:
    """One render in flight: wait for a pose, render the latest, send it, repeat."""
    seq = 0
    while True:
        waiter = asyncio.create_task(latest.ready.wait())
        await asyncio.wait([waiter, reader], return_when=asyncio.FIRST_COMPLETED)
        waiter.cancel()
        if reader.done():
            return
        # The key's render rate applies to live frames too; a frame waits instead of failing.
        while (wait := service.render_limit.acquire(owner)) > 0:
            await asyncio.sleep(wait)
        pose = latest.take()
        if pose is None:
            continue
        started = time.perf_counter()
        try:
            answer = await service.renders.render(model_id, pose.render_request())
        except NoRenderWorker as exc:
            await websocket.close(code=CLOSE_NO_RENDER_WORKER, reason=str(exc)[:120])
            return
        except RenderFailed as exc:
            if exc.status == 404:
                await websocket.close(code=CLOSE_NOT_FOUND, reason=f"no model {model_id!r}")
                return
            await _send_error(websocket, "render_failed", str(exc))
            continue
        seconds = time.perf_counter() - started
        service.metrics.render_seconds.observe(seconds)
        if reader.done():  # the client left during the render
            return
        seq += 1
        head = LiveFrame(
            t=pose.t, seq=seq, media=MEDIA_TYPES[pose.output], render_ms=1000 * seconds,
            dropped=latest.dropped,
        )  # fmt: skip
        try:
            await websocket.send_bytes(pack_live_frame(head, answer.content))
        except RuntimeError:  # closed between the check and the send
            return
