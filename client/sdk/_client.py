"""The two clients: :class:`Client` (blocking) and :class:`AsyncClient` (asyncio), twins over
:class:`~sparsesplat.client.sdk._base._Base`; each adds only its I/O (an httpx client, a
WebSocket for events)."""

from __future__ import annotations

import asyncio
import time
from collections.abc import AsyncIterator, Iterator, Sequence
from pathlib import Path
from typing import Any

import httpx

from sparsesplat.api.cameras import Intrinsics, PinholeCamera
from sparsesplat.api.jobs import Event, Job, JobPage, JobSpec, JobState, Record
from sparsesplat.api.schemas import Health, Readiness
from sparsesplat.api.usage import Usage
from sparsesplat.client.errors import SparsesplatError
from sparsesplat.client.photos import Photos, is_photo_folder, read_photos
from sparsesplat.client.scenes import SceneFormat, TestViews, Upload, from_images, read_scene
from sparsesplat.client.sdk._base import T, _Attempts, _Base, _Call
from sparsesplat.client.sdk._closing import AsyncClosesOnExit, ClosesOnExit
from sparsesplat.client.sdk._config import IdempotencyKey, RetryPolicy, Timeouts
from sparsesplat.client.sdk._events import EventCursor
from sparsesplat.client.sdk.jobs import AsyncJobHandle, JobHandle
from sparsesplat.client.sdk.models import AsyncModelHandle, ModelHandle


class Client(_Base, ClosesOnExit):
    """Blocking client. Use as a context manager or call :meth:`close`.

    Args:
        base_url: service URL (default ``SPARSESPLAT_URL`` or http://127.0.0.1:8000).
        api_key: bearer key (default ``SPARSESPLAT_API_KEY``; none when unset).
        timeouts: :class:`Timeouts`, or one number for reads and renders.
        retry: :class:`RetryPolicy` (``RetryPolicy(max_retries=0)`` disables retries).
        transport: an httpx transport to route requests through (tests, embedding).
    """

    def __init__(
        self,
        base_url: str | None = None,
        api_key: str | None = None,
        timeouts: Timeouts | float | None = None,
        retry: RetryPolicy | None = None,
        transport: httpx.BaseTransport | None = None,
    ) -> None:
        super().__init__(base_url, api_key, timeouts, retry)
        self._http = httpx.Client(**self._http_options(transport))

    def _send(self, call: _Call[T]) -> T:
        attempts = _Attempts(self, call)
        while (wait := attempts.read(self._try(call))) is not None:
            time.sleep(wait)
        return attempts.result

    def _try(self, call: _Call[Any]) -> httpx.Response | httpx.TransportError:
        """One try of ``call``: the answer, or the transport's error."""
        try:
            return self._http.request(call.method, call.path, **self._request_args(call))
        except httpx.TransportError as exc:
            return exc

    # ------------------------------------------------------------ service

    def health(self) -> Health:
        """``GET /healthz``: the server process is up."""
        return self._send(self._c_health())

    def ready(self) -> Readiness:
        """``GET /readyz``: whether jobs and renders would be served now (and what is missing)."""
        return self._send(self._c_ready())

    # ------------------------------------------------------------ jobs

    def submit(
        self,
        upload: Upload | Photos,
        spec: JobSpec | dict[str, Any] | None = None,
        *,
        idempotency_key: IdempotencyKey = "auto",
    ) -> JobHandle:
        """Submit a prepared :class:`~sparsesplat.client.scenes.Upload` (or
        :class:`~sparsesplat.client.photos.Photos`, photos without cameras) as a training job.

        ``spec`` is a :class:`~sparsesplat.api.jobs.JobSpec` or its dict (iterations or
        time_budget_s, preset, depth_prior, seed…); the upload's preset fills in a missing
        one. An ``Idempotency-Key`` is sent (a fresh one unless given), so a retried
        submission returns the first job instead of creating a second."""
        job = self._send(self._c_submit(upload, spec, idempotency_key))
        return JobHandle(self, job, upload if isinstance(upload, Upload) else None)

    def submit_folder(
        self,
        path: str | Path,
        spec: JobSpec | dict[str, Any] | None = None,
        *,
        views: int | None = None,
        test_views: TestViews = "all",
        downscale: int = 1,
        format: SceneFormat | None = None,
        idempotency_key: IdempotencyKey = "auto",
    ) -> JobHandle:
        """Submit a dataset folder in any format the engine reads (LLFF, Blender, DTU,
        instant-ngp, an upload folder) with the paper's training views; see
        :func:`~sparsesplat.client.scenes.read_scene` for the arguments. A folder of photos
        alone (no cameras file) goes up as :meth:`submit_photos`."""
        if format is None and is_photo_folder(Path(path)):
            return self.submit_photos([path], spec, idempotency_key=idempotency_key)
        upload = read_scene(
            path, views=views, test_views=test_views, downscale=downscale, format=format
        )
        return self.submit(upload, spec, idempotency_key=idempotency_key)

    def submit_photos(
        self,
        photos: Sequence[str | Path],
        spec: JobSpec | dict[str, Any] | None = None,
        *,
        intrinsics: Intrinsics | None = None,
        idempotency_key: IdempotencyKey = "auto",
    ) -> JobHandle:
        """Submit photos without cameras (a folder of them, or files): the job estimates their
        cameras first (phase ``estimating cameras``; ``progress.cameras`` says how it went),
        then trains; ``intrinsics`` (pixels, shared) are held fixed when given. Photos that
        cannot be placed fail the job with a message naming them."""
        return self.submit(read_photos(photos, intrinsics), spec, idempotency_key=idempotency_key)

    def submit_images(
        self,
        images: Sequence[Any],
        cameras: Sequence[PinholeCamera],
        spec: JobSpec | dict[str, Any] | None = None,
        *,
        test_images: Sequence[Any] = (),
        test_cameras: Sequence[PinholeCamera] = (),
        idempotency_key: IdempotencyKey = "auto",
    ) -> JobHandle:
        """Submit images (paths, bytes, arrays or PIL images) with their cameras; optional
        held-out images are scored while training. See
        :func:`~sparsesplat.client.scenes.from_images`."""
        upload = from_images(images, cameras, test_images=test_images, test_cameras=test_cameras)
        return self.submit(upload, spec, idempotency_key=idempotency_key)

    def job(self, job_id: str) -> JobHandle:
        """A handle on an existing job (reads its record; :class:`NotFound` if absent)."""
        return JobHandle(self, self._send(self._c_job(job_id)))

    def get_job(self, job_id: str) -> Job:
        """``GET /v1/jobs/{id}``: the job record."""
        return self._send(self._c_job(job_id))

    def jobs(
        self, state: JobState | str | None = None, cursor: str | None = None, limit: int = 20
    ) -> JobPage:
        """One page of your jobs, newest first (follow ``next_cursor``)."""
        return self._send(self._c_jobs(state, cursor, limit))

    def iter_jobs(self, state: JobState | str | None = None, page_size: int = 50) -> Iterator[Job]:
        """Every job of yours, newest first, across pages."""
        cursor = None
        while True:
            page = self.jobs(state, cursor, page_size)
            yield from page.jobs
            if page.next_cursor is None:
                return
            cursor = page.next_cursor

    def cancel(self, job_id: str) -> Job:
        """Cancel a job (a running one stops at its next iteration)."""
        return self._send(self._c_cancel(job_id))

    def delete(self, job_id: str) -> None:
        """Delete a job and every file of it (cancelling it first if needed); its bytes are
        freed at once."""
        self._send(self._c_delete(job_id))

    def usage(self) -> Usage:
        """``GET /v1/usage``: the bytes and jobs your key holds, against the service's limits."""
        return self._send(self._c_usage())

    def metrics(self, job_id: str) -> list[Record]:
        """The job's held-out error records so far, oldest first."""
        return self._send(self._c_metrics(job_id))

    def events(
        self, job_id: str, after: int = 0, *, timeout: float | None = None
    ) -> Iterator[Event]:
        """The job's events with ``seq > after``, then live ones until it ends.

        Over a WebSocket; a dropped connection is reopened with ``?after=<last seq>``, so
        nothing is missed or repeated. Gives up with :class:`ConnectionFailed` after
        ``retry.reconnect_s`` without the server, with :class:`Timeout` after ``timeout``."""
        from websockets.exceptions import ConnectionClosed, InvalidStatus, WebSocketException
        from websockets.sync.client import connect

        cursor = EventCursor(job_id, after, timeout, self.timeouts.event_idle, self.retry)
        while True:
            try:
                with connect(self._ws_url(job_id, cursor.last), **self._ws_options()) as ws:
                    cursor.connected()
                    while True:
                        try:
                            message = ws.recv(timeout=cursor.recv_timeout())
                        except TimeoutError:
                            cursor.idle()
                            break  # idle too long: reconnect
                        event = cursor.accept(message)
                        if event is not None:
                            yield event
                            if cursor.ended:
                                return
            except SparsesplatError:
                raise
            except ConnectionClosed as exc:
                if cursor.closed(exc.rcvd) and self.get_job(job_id).state.terminal:
                    return
            except InvalidStatus as exc:
                # The server refused the handshake (unknown job, bad key): ask over HTTP why.
                self.get_job(job_id)
                raise cursor.refused(exc.response.status_code, exc) from exc
            except (OSError, WebSocketException) as exc:
                cursor.lost(exc, self.base_url)
            time.sleep(cursor.backoff())

    # ------------------------------------------------------------ models

    def model(self, model_id: str) -> ModelHandle:
        """A handle on a trained model (the id of the job that trained it)."""
        return ModelHandle(self, model_id)

    def close(self) -> None:
        """Close the connection pool."""
        self._http.close()

    def __enter__(self) -> Client:
        return self


class AsyncClient(_Base, AsyncClosesOnExit):
    """asyncio twin of :class:`Client` with the same methods as coroutines."""

    def __init__(
        self,
        base_url: str | None = None,
        api_key: str | None = None,
        timeouts: Timeouts | float | None = None,
        retry: RetryPolicy | None = None,
        transport: httpx.AsyncBaseTransport | None = None,
    ) -> None:
        super().__init__(base_url, api_key, timeouts, retry)
        self._http = httpx.AsyncClient(**self._http_options(transport))

    async def _send(self, call: _Call[T]) -> T:
        attempts = _Attempts(self, call)
        while (wait := attempts.read(await self._try(call))) is not None:
            await asyncio.sleep(wait)
        return attempts.result

    async def _try(self, call: _Call[Any]) -> httpx.Response | httpx.TransportError:
        """One try of ``call``: the answer, or the transport's error."""
        try:
            return await self._http.request(call.method, call.path, **self._request_args(call))
        except httpx.TransportError as exc:
            return exc

    async def health(self) -> Health:
        """``GET /healthz``."""
        return await self._send(self._c_health())

    async def ready(self) -> Readiness:
        """``GET /readyz``."""
        return await self._send(self._c_ready())

    async def submit(
        self,
        upload: Upload | Photos,
        spec: JobSpec | dict[str, Any] | None = None,
        *,
        idempotency_key: IdempotencyKey = "auto",
    ) -> AsyncJobHandle:
        """See :meth:`Client.submit`."""
        job = await self._send(self._c_submit(upload, spec, idempotency_key))
        return AsyncJobHandle(self, job, upload if isinstance(upload, Upload) else None)

    async def submit_folder(
        self,
        path: str | Path,
        spec: JobSpec | dict[str, Any] | None = None,
        *,
        views: int | None = None,
        test_views: TestViews = "all",
        downscale: int = 1,
        format: SceneFormat | None = None,
        idempotency_key: IdempotencyKey = "auto",
    ) -> AsyncJobHandle:
        """See :meth:`Client.submit_folder` (the folder is read in a thread)."""
        if format is None and is_photo_folder(Path(path)):
            return await self.submit_photos([path], spec, idempotency_key=idempotency_key)
        upload = await asyncio.to_thread(
            read_scene, path, views=views, test_views=test_views, downscale=downscale,
            format=format,
        )  # fmt: skip
        return await self.submit(upload, spec, idempotency_key=idempotency_key)

    async def submit_photos(
        self,
        photos: Sequence[str | Path],
        spec: JobSpec | dict[str, Any] | None = None,
        *,
        intrinsics: Intrinsics | None = None,
        idempotency_key: IdempotencyKey = "auto",
    ) -> AsyncJobHandle:
        """See :meth:`Client.submit_photos` (the photos are read in a thread)."""
        upload = await asyncio.to_thread(read_photos, photos, intrinsics)
        return await self.submit(upload, spec, idempotency_key=idempotency_key)

    async def submit_images(
        self,
        images: Sequence[Any],
        cameras: Sequence[PinholeCamera],
        spec: JobSpec | dict[str, Any] | None = None,
        *,
        test_images: Sequence[Any] = (),
        test_cameras: Sequence[PinholeCamera] = (),
        idempotency_key: IdempotencyKey = "auto",
    ) -> AsyncJobHandle:
        """See :meth:`Client.submit_images`."""
        upload = from_images(images, cameras, test_images=test_images, test_cameras=test_cameras)
        return await self.submit(upload, spec, idempotency_key=idempotency_key)

    async def job(self, job_id: str) -> AsyncJobHandle:
        """See :meth:`Client.job`."""
        return AsyncJobHandle(self, await self._send(self._c_job(job_id)))

    async def get_job(self, job_id: str) -> Job:
        """See :meth:`Client.get_job`."""
        return await self._send(self._c_job(job_id))

    async def jobs(
        self, state: JobState | str | None = None, cursor: str | None = None, limit: int = 20
    ) -> JobPage:
        """See :meth:`Client.jobs`."""
        return await self._send(self._c_jobs(state, cursor, limit))

    async def iter_jobs(
        self, state: JobState | str | None = None, page_size: int = 50
    ) -> AsyncIterator[Job]:
        """See :meth:`Client.iter_jobs`."""
        cursor = None
        while True:
            page = await self.jobs(state, cursor, page_size)
            for job in page.jobs:
                yield job
            if page.next_cursor is None:
                return
            cursor = page.next_cursor

    async def cancel(self, job_id: str) -> Job:
        """See :meth:`Client.cancel`."""
        return await self._send(self._c_cancel(job_id))

    async def delete(self, job_id: str) -> None:
        """See :meth:`Client.delete`."""
        await self._send(self._c_delete(job_id))

    async def usage(self) -> Usage:
        """See :meth:`Client.usage`."""
        return await self._send(self._c_usage())

    async def metrics(self, job_id: str) -> list[Record]:
        """See :meth:`Client.metrics`."""
        return await self._send(self._c_metrics(job_id))

    async def events(
        self, job_id: str, after: int = 0, *, timeout: float | None = None
    ) -> AsyncIterator[Event]:
        """See :meth:`Client.events`."""
        from websockets.asyncio.client import connect
        from websockets.exceptions import ConnectionClosed, InvalidStatus, WebSocketException

        cursor = EventCursor(job_id, after, timeout, self.timeouts.event_idle, self.retry)
        while True:
            try:
                async with connect(self._ws_url(job_id, cursor.last), **self._ws_options()) as ws:
                    cursor.connected()
                    while True:
                        try:
                            message = await asyncio.wait_for(ws.recv(), cursor.recv_timeout())
                        except TimeoutError:
                            cursor.idle()
                            break  # idle too long: reconnect
                        event = cursor.accept(message)
                        if event is not None:
                            yield event
                            if cursor.ended:
                                return
            except SparsesplatError:
                raise
            except ConnectionClosed as exc:
                if cursor.closed(exc.rcvd) and (await self.get_job(job_id)).state.terminal:
                    return
            except InvalidStatus as exc:
                await self.get_job(job_id)
                raise cursor.refused(exc.response.status_code, exc) from exc
            except (OSError, WebSocketException) as exc:
                cursor.lost(exc, self.base_url)
            await asyncio.sleep(cursor.backoff())

    def model(self, model_id: str) -> AsyncModelHandle:
        """See :meth:`Client.model`."""
        return AsyncModelHandle(self, model_id)

    async def aclose(self) -> None:
        """Close the connection pool."""
        await self._http.aclose()

    async def __aenter__(self) -> AsyncClient:
        return self
