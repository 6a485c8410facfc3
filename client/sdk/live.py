"""The live view (``/v1/models/{id}/live``): :class:`LiveView` and its asyncio twin
:class:`AsyncLiveView`, side by side over :class:`_LiveSession`, which holds everything that is
not I/O (pose messages, frame decoding, the error a message or close code means, how many poses
are still owed a frame).

The server renders one pose at a time per connection and only the newest one waiting: poses
overtaken while a render runs are dropped (each frame's ``dropped`` counts them). Every pose
sent is therefore answered by a frame, counted as dropped, or answered with an error; iterating
a view yields frames until every pose sent so far is accounted for.
"""

from __future__ import annotations

import asyncio
import contextlib
import json
import time
from collections.abc import AsyncIterator, Iterator
from typing import TYPE_CHECKING, Any

from sparsesplat.api.cameras import PinholeCamera
from sparsesplat.api.renders import LiveFrame, LiveOutput, RenderMode, unpack_live_frame
from sparsesplat.client.errors import (
    APIError,
    AuthenticationError,
    Conflict,
    ConnectionFailed,
    NotFound,
    ServerError,
    ServiceUnavailable,
    SparsesplatError,
    Timeout,
    ValidationFailed,
)
from sparsesplat.client.sdk._base import _camera_json
from sparsesplat.client.sdk._closing import AsyncClosesOnExit, ClosesOnExit

if TYPE_CHECKING:
    from websockets.asyncio.client import ClientConnection as AsyncConnection
    from websockets.sync.client import ClientConnection

    from sparsesplat.client.sdk._base import _Base

LiveFrameData = tuple[LiveFrame, bytes]
"""One frame of the live view: its header and the encoded image."""

_CLOSE_ERRORS: dict[int, tuple[type[APIError], int, str]] = {
    4401: (AuthenticationError, 401, "unauthenticated"),
    4404: (NotFound, 404, "model_not_found"),
    4409: (Conflict, 409, "model_not_ready"),
    4503: (ServiceUnavailable, 503, "no_render_worker"),
}
"""The server's close codes (server/routes/live.py) as the SDK's errors."""


def _open_failed(url: str, exc: Exception) -> SparsesplatError:
    """The SDK's error for a live view that could not be opened: a refused handshake (an HTTP
    status instead of the upgrade) or no connection at all."""
    from websockets.exceptions import InvalidStatus

    if isinstance(exc, InvalidStatus):
        return ServerError(exc.response.status_code, "live_refused", f"live view refused: {exc}")
    return ConnectionFailed(f"cannot open the live view {url}: {exc}")


class _LiveSession:
    """The transport-free half of a live view on one model."""

    def __init__(
        self,
        client: _Base,
        model_id: str,
        output: LiveOutput,
        quality: int,
        mode: RenderMode,
        downscale: int,
    ) -> None:
        self.model_id = model_id
        self.url = client._live_url(model_id)
        # max_size: a frame is as large as the image asked for.
        self._connect_args: dict[str, Any] = client._ws_options() | {"max_size": None}
        self._recv_s = client.timeouts.render
        self._options: dict[str, Any] = {
            "output": output, "quality": quality, "mode": mode, "downscale": downscale,
        }  # fmt: skip
        self.sent = 0
        """Poses sent on this connection."""
        self.refused = 0
        """Poses answered with an error message (invalid, or their render failed)."""
        self.last: LiveFrame | None = None
        """The header of the latest frame received."""

    @property
    def pending(self) -> int:
        """Poses sent that are not yet rendered, dropped (overtaken by a newer one) or
        refused."""
        framed = self.last.seq + self.last.dropped if self.last is not None else 0
        return self.sent - framed - self.refused

    def _pose(self, camera: PinholeCamera | dict[str, Any], t: float | None) -> tuple[str, float]:
        """The text message of one pose and its ``t`` (now, in ms, unless given)."""
        stamp = time.time() * 1000.0 if t is None else float(t)
        message = json.dumps({"camera": _camera_json(camera), "t": stamp, **self._options})
        self.sent += 1
        return message, stamp

    def _frame(self, message: str | bytes) -> LiveFrameData:
        """The frame of a binary message; the error of a text one (the connection stays
        open: the next pose can be sent)."""
        if isinstance(message, str):
            self.refused += 1
            try:
                body = json.loads(message)
                code, text = str(body["code"]), str(body["message"])
            except (ValueError, KeyError, TypeError):
                raise ServerError(500, "invalid_answer", f"live view: {message[:200]}") from None
            if code == "render_failed":
                raise ServerError(500, code, text)
            raise ValidationFailed(422, code, text)
        header, image = unpack_live_frame(message)
        self.last = header
        return header, image

    def _closed(self, frame: Any, exc: Exception) -> SparsesplatError:
        """The error for the server closing the connection with close ``frame``."""
        code = frame.code if frame is not None else None
        reason = frame.reason if frame is not None else ""
        if code in _CLOSE_ERRORS:
            kind, status, name = _CLOSE_ERRORS[code]
            return kind(status, name, reason or f"live view of {self.model_id!r} refused")
        return ConnectionFailed(f"live view {self.url} closed: {exc}")

    def _timed_out(self, seconds: float) -> Timeout:
        return Timeout(f"live view of {self.model_id!r}: no frame within {seconds} s")


class LiveView(_LiveSession, ClosesOnExit):
    """A live view on a model: send camera poses, receive server renders as they are ready.

    Open it with :meth:`ModelHandle.live <sparsesplat.client.sdk.models.ModelHandle.live>`
    and use it as a context manager (the connection opens on the first :meth:`send` when not
    already open)::

        with model.live(output="png") as view:
            view.send(camera)
            header, image = view.recv()
    """

    _ws: ClientConnection | None = None
    _stack: contextlib.ExitStack | None = None

    def connect(self) -> LiveView:
        """Open the WebSocket (:meth:`send` and :meth:`recv` do when needed)."""
        self._open()
        return self

    def _open(self) -> ClientConnection:
        from websockets.exceptions import WebSocketException
        from websockets.sync.client import connect

        if self._ws is None:
            # Entered as a context manager (websockets 17 deprecates using it bare); the
            # stack exits it on close().
            stack = contextlib.ExitStack()
            try:
                self._ws = stack.enter_context(connect(self.url, **self._connect_args))
            except (OSError, WebSocketException) as exc:
                raise _open_failed(self.url, exc) from exc
            self._stack = stack
        return self._ws

    def send(self, camera: PinholeCamera | dict[str, Any], *, t: float | None = None) -> float:
        """Ask for a render from ``camera``; returns the pose's ``t`` (echoed by its frame;
        default: now, in milliseconds since the epoch). A newer pose sent before this one's
        render starts replaces it."""
        from websockets.exceptions import ConnectionClosed

        ws = self._open()
        message, stamp = self._pose(camera, t)
        try:
            ws.send(message)
        except ConnectionClosed as exc:
            raise self._closed(exc.rcvd, exc) from exc
        return stamp

    def recv(self, timeout: float | None = None) -> LiveFrameData:
        """The next frame (header, image bytes). Raises :class:`ValidationFailed` for a pose
        the server refused, :class:`Timeout` after ``timeout`` seconds (default: the client's
        render timeout), and the error of the close code when the server closes."""
        from websockets.exceptions import ConnectionClosed

        ws = self._open()
        seconds = self._recv_s if timeout is None else timeout
        try:
            message = ws.recv(timeout=seconds)
        except TimeoutError:
            raise self._timed_out(seconds) from None
        except ConnectionClosed as exc:
            raise self._closed(exc.rcvd, exc) from exc
        return self._frame(message)

    def __iter__(self) -> Iterator[LiveFrameData]:
        """Frames until every pose sent so far is rendered, dropped or refused."""
        while self.pending > 0:
            yield self.recv()

    def close(self) -> None:
        """Close the connection."""
        stack, self._stack, self._ws = self._stack, None, None
        if stack is not None:
            stack.close()

    def __enter__(self) -> LiveView:
        return self.connect()


class AsyncLiveView(_LiveSession, AsyncClosesOnExit):
    """asyncio twin of :class:`LiveView` (``async with model.live() as view``)."""

    _ws: AsyncConnection | None = None

    async def connect(self) -> AsyncLiveView:
        """See :meth:`LiveView.connect`."""
        await self._open()
        return self

    async def _open(self) -> AsyncConnection:
        from websockets.asyncio.client import connect
        from websockets.exceptions import WebSocketException

        if self._ws is None:
            try:
                self._ws = await connect(self.url, **self._connect_args)
            except (OSError, WebSocketException) as exc:
                raise _open_failed(self.url, exc) from exc
        return self._ws

    async def send(
        self, camera: PinholeCamera | dict[str, Any], *, t: float | None = None
    ) -> float:
        """See :meth:`LiveView.send`."""
        from websockets.exceptions import ConnectionClosed

        ws = await self._open()
        message, stamp = self._pose(camera, t)
        try:
            await ws.send(message)
        except ConnectionClosed as exc:
            raise self._closed(exc.rcvd, exc) from exc
        return stamp

    async def recv(self, timeout: float | None = None) -> LiveFrameData:
        """See :meth:`LiveView.recv`."""
        from websockets.exceptions import ConnectionClosed

        ws = await self._open()
        seconds = self._recv_s if timeout is None else timeout
        try:
            message = await asyncio.wait_for(ws.recv(), seconds)
        except TimeoutError:
            raise self._timed_out(seconds) from None
        except ConnectionClosed as exc:
            raise self._closed(exc.rcvd, exc) from exc
        return self._frame(message)

    async def __aiter__(self) -> AsyncIterator[LiveFrameData]:
        """See :meth:`LiveView.__iter__`."""
        while self.pending > 0:
            yield await self.recv()

    async def aclose(self) -> None:
        """Close the connection."""
        if self._ws is not None:
            await self._ws.close()
            self._ws = None

    async def __aenter__(self) -> AsyncLiveView:
        return await self.connect()
