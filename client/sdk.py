"""Sync and async clients as twins over one base that builds requests and parses answers.

``Client`` and ``AsyncClient`` have the same methods (the async ones are coroutines); so do
their job handles (``JobHandle`` / ``AsyncJobHandle``) and model handles (``ModelHandle`` /
``AsyncModelHandle``). Everything that is not I/O — URLs, headers, retry decisions, decoding,
error mapping — lives once in :class:`_Base` and the module-level helpers.

Both clients accept an injectable httpx ``transport``, so tests and embedders can route
requests anywhere (e.g. ``httpx.ASGITransport`` to an in-process app); the event stream is a
WebSocket and needs a real server.
"""

from __future__ import annotations

import asyncio
import json
import os
import random
import time
import uuid
import zipfile
from collections.abc import AsyncIterator, Callable, Iterator, Sequence
from dataclasses import dataclass, field
from io import BytesIO
from pathlib import Path
from types import TracebackType
from typing import TYPE_CHECKING, Any, Generic, Literal, TypeVar
from urllib.parse import urlencode

import httpx
from pydantic import BaseModel, TypeAdapter, ValidationError

from sparsesplat.api.cameras import PinholeCamera
from sparsesplat.api.jobs import Event, Job, JobPage, JobSpec, JobState, ModelInfo, Record
from sparsesplat.api.renders import RENDER_WARNING_HEADER, RenderOutput
from sparsesplat.api.schemas import ErrorBody, Health, Readiness
from sparsesplat.client import cameras as cams
from sparsesplat.client import media
from sparsesplat.client.errors import (
    APIError,
    AuthenticationError,
    ConnectionFailed,
    InvalidInput,
    JobFailed,
    NotFound,
    RenderWarning,
    ServerError,
    SparsesplatError,
    Timeout,
    error_for_status,
    warn_about,
)
from sparsesplat.client.progress import ProgressBar
from sparsesplat.client.scenes import SceneFormat, TestViews, Upload, from_images, read_scene

if TYPE_CHECKING:
    import numpy as np
    import pandas as pd
    from PIL import Image

DEFAULT_URL = "http://127.0.0.1:8000"
"""Where the clients connect when no URL is given and ``SPARSESPLAT_URL`` is unset."""
URL_ENV = "SPARSESPLAT_URL"
"""Environment variable holding the service URL."""
API_KEY_ENV = "SPARSESPLAT_API_KEY"
"""Environment variable holding the API key."""

T = TypeVar("T")
ModelT = TypeVar("ModelT", bound=BaseModel)
ExportFormat = Literal["ply", "splat", "checkpoint"]
"""What :meth:`ModelHandle.export` downloads."""
IdempotencyKey = str | Literal["auto"] | None
"""``"auto"``: a fresh random key per submission (retries reuse it); None: send none (and do
not retry the submission)."""
EventCallback = Callable[[Event], Any]
"""Called with each event ``wait()`` sees."""

_RECORDS = TypeAdapter(list[Record])
_TERMINAL = {"succeeded", "failed", "cancelled"}
_SUFFIX_OUTPUT: dict[str, RenderOutput] = {
    ".png": "png",
    ".jpg": "jpeg",
    ".jpeg": "jpeg",
    ".webp": "webp",
    ".npy": "npy",
}


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


@dataclass
class _Call(Generic[T]):
    """One HTTP request and how to read its answer."""

    method: str
    path: str
    decode: Callable[[httpx.Response], T]
    timeout: float
    idempotent: bool
    params: dict[str, Any] | None = None
    json: Any = None
    files: list[tuple[str, tuple[str, bytes, str]]] | None = None
    data: dict[str, str] | None = None
    headers: dict[str, str] = field(default_factory=dict)
    ok_statuses: tuple[int, ...] = ()
    """Error statuses whose body ``decode`` still reads (``/readyz`` answers 503)."""
    missing_ok_on_retry: bool = False
    """A retried DELETE whose first attempt went through answers 404: that is success."""


def _retry_after(response: httpx.Response) -> float | None:
    value = response.headers.get("retry-after")
    if value is None:
        return None
    try:
        return float(value)
    except ValueError:
        return None


def _api_error(response: httpx.Response) -> APIError:
    try:
        body = ErrorBody.model_validate_json(response.content)
        code, message = body.code, body.message
    except ValueError:
        code, message = f"http_{response.status_code}", response.text[:500]
    return error_for_status(response.status_code, code, message, _retry_after(response))


def _model(model: type[ModelT]) -> Callable[[httpx.Response], ModelT]:
    def decode(response: httpx.Response) -> ModelT:
        try:
            return model.model_validate_json(response.content)
        except ValidationError as exc:
            raise ServerError(
                response.status_code, "invalid_answer", f"unexpected answer: {exc}"
            ) from exc

    return decode


def _content(response: httpx.Response) -> bytes:
    return response.content


def _render_content(response: httpx.Response) -> bytes:
    """A render's bytes; a :class:`RenderWarning` when the service says it sees nothing."""
    message = response.headers.get(RENDER_WARNING_HEADER)
    if message:
        import warnings

        warnings.warn(f"render: {message}", RenderWarning, stacklevel=4)
    return response.content


def _nothing(response: httpx.Response) -> None:
    return None


def _records(response: httpx.Response) -> list[Record]:
    return _RECORDS.validate_json(response.content)


def _unzip(data: bytes) -> list[bytes]:
    with zipfile.ZipFile(BytesIO(data)) as archive:
        return [archive.read(name) for name in sorted(archive.namelist())]


def _camera_json(camera: PinholeCamera | dict[str, Any]) -> Any:
    """A camera for the wire: a PinholeCamera as JSON, a dict as given (the server checks it
    and says what is wrong)."""
    if isinstance(camera, PinholeCamera):
        return camera.model_dump(mode="json")
    return camera


def _spec_json(spec: JobSpec | dict[str, Any] | None, preset: str | None) -> str:
    data = (
        spec.model_dump(mode="json", exclude_unset=True)
        if isinstance(spec, JobSpec)
        else dict(spec or {})
    )
    if preset is not None and data.get("preset") is None:
        data["preset"] = preset
    try:
        JobSpec.model_validate(data)
    except ValidationError as exc:
        raise InvalidInput(f"spec: {exc.errors()[0]['msg']} ({exc.errors()[0]['loc']})") from exc
    return json.dumps(data)


def _output_for(path: Path, output: RenderOutput | None) -> RenderOutput:
    if output is not None:
        return output
    try:
        return _SUFFIX_OUTPUT[path.suffix.lower()]
    except KeyError:
        raise InvalidInput(
            f"{path}: cannot tell the output from the suffix; use .png, .jpg, .webp or .npy, "
            "or pass output="
        ) from None


def _terminal(event: Event) -> bool:
    return event.type == "state" and event.data.get("state") in _TERMINAL


class _Base:
    """What both clients share: base URL, auth header, timeouts, retries, request building."""

    def __init__(
        self,
        base_url: str | None,
        api_key: str | None,
        timeouts: Timeouts | float | None,
        retry: RetryPolicy | None,
    ) -> None:
        self.base_url = (base_url or os.environ.get(URL_ENV) or DEFAULT_URL).rstrip("/")
        key = api_key if api_key is not None else os.environ.get(API_KEY_ENV)
        self._headers = {"Authorization": f"Bearer {key}"} if key else {}
        if isinstance(timeouts, int | float):
            timeouts = Timeouts(read=float(timeouts), render=float(timeouts))
        self.timeouts = timeouts or DEFAULT_TIMEOUTS
        """The named timeouts in force."""
        self.retry = retry or DEFAULT_RETRY
        """The retry policy in force."""

    # ------------------------------------------------------------ request building

    def _timeout(self, read: float) -> httpx.Timeout:
        return httpx.Timeout(read, connect=self.timeouts.connect)

    def _should_retry(self, call: _Call[Any], attempt: int, error: BaseException) -> float | None:
        """Seconds to wait before retrying ``call`` after ``error``, or None to give up."""
        if not call.idempotent or attempt > self.retry.max_retries:
            return None
        if isinstance(error, ConnectionFailed | Timeout):
            return self.retry.delay(attempt)
        if isinstance(error, APIError) and error.status in self.retry.retry_statuses:
            if error.status == 429 and (error.retry_after or 0) > self.retry.max_backoff_s:
                return None
            return self.retry.delay(attempt, error.retry_after)
        return None

    def _finish(self, call: _Call[T], response: httpx.Response, attempt: int) -> T:
        if response.is_success or response.status_code in call.ok_statuses:
            return call.decode(response)
        if response.status_code == 404 and call.missing_ok_on_retry and attempt > 1:
            return call.decode(response)
        raise _api_error(response)

    def _transport_error(self, call: _Call[Any], exc: httpx.TransportError) -> Exception:
        where = f"{call.method} {self.base_url}{call.path}"
        if isinstance(exc, httpx.TimeoutException):
            return Timeout(f"{where}: no answer within the timeout ({type(exc).__name__})")
        return ConnectionFailed(f"cannot reach {where}: {exc or type(exc).__name__}")

    def _request_args(self, call: _Call[Any]) -> dict[str, Any]:
        args: dict[str, Any] = {"timeout": self._timeout(call.timeout)}
        for name in ("params", "json", "files", "data"):
            value = getattr(call, name)
            if value is not None:
                args[name] = value
        if call.headers:
            args["headers"] = call.headers
        return args

    def _ws_url(self, job_id: str, after: int) -> str:
        base = self.base_url
        scheme = "wss" if base.startswith("https") else "ws"
        return f"{scheme}{base[base.index(':') :]}/v1/jobs/{job_id}/events?" + urlencode(
            {"after": after}
        )

    # ------------------------------------------------------------ calls

    def _c_health(self) -> _Call[Health]:
        return _Call("GET", "/healthz", _model(Health), self.timeouts.read, True)

    def _c_ready(self) -> _Call[Readiness]:
        return _Call(
            "GET", "/readyz", _model(Readiness), self.timeouts.read, True, ok_statuses=(503,)
        )

    def _c_submit(
        self,
        upload: Upload,
        spec: JobSpec | dict[str, Any] | None,
        idempotency_key: IdempotencyKey,
    ) -> _Call[Job]:
        upload.validate()
        files: list[tuple[str, tuple[str, bytes, str]]] = [
            ("cameras", ("cameras.json", json.dumps(upload.cameras).encode(), "application/json"))
        ]
        for name, data in upload.images.items():
            kind = media.sniff(data) or "png"
            files.append(("images", (name, data, media.UPLOAD_FORMATS[kind])))
        for name, data in upload.depths.items():
            files.append(("depths", (name, data, "application/octet-stream")))
        for name, data in upload.masks.items():
            files.append(("masks", (name, data, media.UPLOAD_FORMATS[media.sniff(data) or "png"])))
        key = uuid.uuid4().hex if idempotency_key == "auto" else idempotency_key
        return _Call(
            "POST",
            "/v1/jobs",
            _model(Job),
            self.timeouts.upload,
            idempotent=key is not None,
            files=files,
            data={"spec": _spec_json(spec, upload.preset)},
            headers={"Idempotency-Key": key} if key else {},
        )

    def _c_job(self, job_id: str) -> _Call[Job]:
        return _Call("GET", f"/v1/jobs/{job_id}", _model(Job), self.timeouts.read, True)

    def _c_jobs(
        self, state: JobState | str | None, cursor: str | None, limit: int
    ) -> _Call[JobPage]:
        params: dict[str, Any] = {"limit": limit}
        if state is not None:
            params["state"] = JobState(state).value
        if cursor is not None:
            params["cursor"] = cursor
        return _Call("GET", "/v1/jobs", _model(JobPage), self.timeouts.read, True, params=params)

    def _c_cancel(self, job_id: str) -> _Call[Job]:
        return _Call("POST", f"/v1/jobs/{job_id}/cancel", _model(Job), self.timeouts.read, True)

    def _c_delete(self, job_id: str) -> _Call[None]:
        return _Call(
            "DELETE", f"/v1/jobs/{job_id}", _nothing, self.timeouts.read, True,
            missing_ok_on_retry=True,
        )  # fmt: skip

    def _c_metrics(self, job_id: str) -> _Call[list[Record]]:
        return _Call("GET", f"/v1/jobs/{job_id}/metrics", _records, self.timeouts.read, True)

    def _c_metrics_csv(self, job_id: str) -> _Call[bytes]:
        return _Call(
            "GET", f"/v1/jobs/{job_id}/metrics", _content, self.timeouts.read, True,
            params={"format": "csv"},
        )  # fmt: skip

    def _c_metrics_plot(self, job_id: str) -> _Call[bytes]:
        return _Call("GET", f"/v1/jobs/{job_id}/metrics.png", _content, self.timeouts.read, True)

    def _c_model(self, model_id: str) -> _Call[ModelInfo]:
        return _Call("GET", f"/v1/models/{model_id}", _model(ModelInfo), self.timeouts.read, True)

    def _c_render(
        self,
        model_id: str,
        camera: PinholeCamera | dict[str, Any] | None,
        path: Sequence[PinholeCamera | dict[str, Any]] | None,
        output: RenderOutput,
        downscale: int,
        quality: int,
    ) -> _Call[bytes]:
        body: dict[str, Any] = {"output": output, "downscale": downscale, "quality": quality}
        timeout = self.timeouts.render
        if path is not None:
            body["path"] = [_camera_json(c) for c in path]
            timeout = min(self.timeouts.render * max(1, len(path)), self.timeouts.download)
        else:
            body["camera"] = _camera_json(camera) if camera is not None else None
        return _Call(
            "POST", f"/v1/models/{model_id}/render", _render_content, timeout, True, json=body
        )

    def _c_export(self, model_id: str, format: ExportFormat) -> _Call[bytes]:
        if format not in ("ply", "splat", "checkpoint"):
            raise InvalidInput(f"export format {format!r}: use 'ply', 'splat' or 'checkpoint'")
        return _Call(
            "GET", f"/v1/models/{model_id}/export/{format}", _content, self.timeouts.download, True
        )


def _ws_failure(code: int | None, reason: str, job_id: str) -> APIError | None:
    """The error a WebSocket close code stands for (None: worth reconnecting)."""
    if code == 4404:
        return NotFound(404, "job_not_found", reason or f"no job {job_id!r}")
    if code == 4401:
        return AuthenticationError(401, "unauthenticated", reason or "missing or unknown API key")
    return None


# ==================================================================== blocking


class Client(_Base):
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
        self._http = httpx.Client(
            base_url=self.base_url,
            headers=self._headers,
            timeout=self._timeout(self.timeouts.read),
            transport=transport,
        )

    def _send(self, call: _Call[T]) -> T:
        attempt = 1
        while True:
            try:
                try:
                    response = self._http.request(
                        call.method, call.path, **self._request_args(call)
                    )
                except httpx.TransportError as exc:
                    raise self._transport_error(call, exc) from exc
                return self._finish(call, response, attempt)
            except (APIError, ConnectionFailed, Timeout) as exc:
                wait = self._should_retry(call, attempt, exc)
                if wait is None:
                    raise
            time.sleep(wait)
            attempt += 1

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
        upload: Upload,
        spec: JobSpec | dict[str, Any] | None = None,
        *,
        idempotency_key: IdempotencyKey = "auto",
    ) -> JobHandle:
        """Submit a prepared :class:`~sparsesplat.client.scenes.Upload` as a training job.

        ``spec`` is a :class:`~sparsesplat.api.jobs.JobSpec` or its dict (iterations or
        time_budget_s, preset, depth_prior, seed…); the upload's preset fills in a missing
        one. An ``Idempotency-Key`` is sent (a fresh one unless given), so a retried
        submission returns the first job instead of creating a second."""
        job = self._send(self._c_submit(upload, spec, idempotency_key))
        return JobHandle(self, job, upload)

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
        :func:`~sparsesplat.client.scenes.read_scene` for the arguments."""
        upload = read_scene(
            path, views=views, test_views=test_views, downscale=downscale, format=format
        )
        return self.submit(upload, spec, idempotency_key=idempotency_key)

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
        """Delete a job and every file of it (cancelling it first if needed)."""
        self._send(self._c_delete(job_id))

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

        deadline = None if timeout is None else time.monotonic() + timeout
        last, lost_since, attempt = after, None, 0
        while True:
            try:
                with connect(
                    self._ws_url(job_id, last),
                    additional_headers=self._headers,
                    open_timeout=self.timeouts.connect,
                    close_timeout=2,
                ) as ws:
                    lost_since, attempt = None, 0
                    while True:
                        wait = self.timeouts.event_idle
                        if deadline is not None:
                            wait = min(wait, deadline - time.monotonic())
                            if wait <= 0:
                                raise Timeout(f"job {job_id}: no end within {timeout} s")
                        try:
                            message = ws.recv(timeout=wait)
                        except TimeoutError:
                            if deadline is not None and time.monotonic() >= deadline:
                                raise Timeout(f"job {job_id}: no end within {timeout} s") from None
                            break  # idle too long: reconnect
                        event = Event.model_validate_json(message)
                        if event.seq <= last:
                            continue
                        last = event.seq
                        yield event
                        if _terminal(event):
                            return
            except SparsesplatError:
                raise
            except ConnectionClosed as exc:
                code = exc.rcvd.code if exc.rcvd is not None else None
                failure = _ws_failure(code, exc.rcvd.reason if exc.rcvd else "", job_id)
                if failure is not None:
                    raise failure from exc
                if code == 1000 and self.get_job(job_id).state.terminal:
                    return
            except InvalidStatus as exc:
                # The server refused the handshake (unknown job, bad key): ask over HTTP why.
                self.get_job(job_id)
                raise ServerError(
                    exc.response.status_code, "events_refused", f"event stream refused: {exc}"
                ) from exc
            except (OSError, WebSocketException) as exc:
                lost_since = lost_since or time.monotonic()
                if time.monotonic() - lost_since > self.retry.reconnect_s:
                    raise ConnectionFailed(
                        f"lost the event stream of job {job_id} at {self.base_url}: {exc}"
                    ) from exc
            attempt += 1
            time.sleep(self.retry.delay(min(attempt, 5)))

    # ------------------------------------------------------------ models

    def model(self, model_id: str) -> ModelHandle:
        """A handle on a trained model (the id of the job that trained it)."""
        return ModelHandle(self, model_id)

    def close(self) -> None:
        """Close the connection pool."""
        self._http.close()

    def __enter__(self) -> Client:
        return self

    def __exit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        tb: TracebackType | None,
    ) -> None:
        self.close()


class JobHandle:
    """A submitted job: its latest record in :attr:`info`, and what can be done with it."""

    def __init__(self, client: Client, info: Job, upload: Upload | None = None) -> None:
        self.client = client
        self.info = info
        """The job record as last read."""
        self.upload = upload
        """What was submitted (when this handle came from a submission)."""

    @property
    def id(self) -> str:
        """Job id (also its model's)."""
        return self.info.id

    @property
    def state(self) -> JobState:
        """State as last read (see :meth:`refresh`)."""
        return self.info.state

    def refresh(self) -> Job:
        """Read the job record again."""
        self.info = self.client.get_job(self.id)
        return self.info

    def events(self, after: int = 0, *, timeout: float | None = None) -> Iterator[Event]:
        """Stored then live events, resuming after dropped connections (see
        :meth:`Client.events`)."""
        return self.client.events(self.id, after, timeout=timeout)

    def wait(
        self,
        timeout: float | None = None,
        *,
        progress: bool | None = None,
        callback: EventCallback | None = None,
        raise_on_failure: bool = True,
    ) -> Job:
        """Block until the job ends; return its final record.

        Args:
            timeout: seconds to wait at most (:class:`Timeout` after).
            progress: show a tqdm bar (None: when stderr is a terminal).
            callback: called with every event (state, progress, record).
            raise_on_failure: raise :class:`JobFailed` when it ends failed or cancelled.
        """
        bar = ProgressBar(self.id, progress)
        try:
            for event in self.events(timeout=timeout):
                bar.update(event)
                if callback is not None:
                    callback(event)
        finally:
            bar.close()
        job = self.refresh()
        warn_about(job)
        if raise_on_failure and job.state != JobState.succeeded:
            raise JobFailed(job)
        return job

    def metrics(self) -> list[Record]:
        """Held-out error records so far (the error-against-time curve)."""
        return self.client.metrics(self.id)

    def metrics_frame(self) -> pd.DataFrame:
        """:meth:`metrics` as a pandas DataFrame (``pandas`` extra)."""
        return _frame(self.metrics())

    def metrics_plot(self, path: str | Path) -> Path:
        """Save the server's plot of the error against run time as PNG."""
        return _write(path, self.client._send(self.client._c_metrics_plot(self.id)))

    def cancel(self) -> Job:
        """Ask the job to stop."""
        self.info = self.client.cancel(self.id)
        return self.info

    def delete(self) -> None:
        """Delete the job and all its files."""
        self.client.delete(self.id)

    @property
    def model(self) -> ModelHandle:
        """The job's model (renders and exports once it has succeeded)."""
        return ModelHandle(self.client, self.id)

    def __repr__(self) -> str:
        return f"JobHandle({self.id!r}, state={self.state.value!r})"


class ModelHandle:
    """A trained model: renders at any camera, camera paths, videos and exports."""

    def __init__(self, client: Client, model_id: str) -> None:
        self.client = client
        self.id = model_id
        """Model id (= the job id)."""

    def info(self) -> ModelInfo:
        """Size, final metrics, exports and the cameras it was trained with."""
        return self.client._send(self.client._c_model(self.id))

    def cameras(self, split: str | None = "train") -> list[PinholeCamera]:
        """The uploaded cameras of ``split`` (``train``, ``test``; None: all)."""
        return _model_cameras(self.info(), split)

    def render_bytes(
        self,
        camera: PinholeCamera | dict[str, Any],
        output: RenderOutput = "png",
        *,
        downscale: int = 1,
        quality: int = 90,
    ) -> bytes:
        """The encoded render (PNG/JPEG/WebP image, 16-bit depth PNG, .npy depth, alpha)."""
        call = self.client._c_render(self.id, camera, None, output, downscale, quality)
        return self.client._send(call)

    def render(self, camera: PinholeCamera | dict[str, Any], *, downscale: int = 1) -> np.ndarray:
        """The render as an (H, W, 3) uint8 array (``images`` extra)."""
        return media.decode_array(self.render_bytes(camera, downscale=downscale))

    def render_image(
        self, camera: PinholeCamera | dict[str, Any], *, downscale: int = 1
    ) -> Image.Image:
        """The render as a PIL image (``images`` extra)."""
        return media.decode_image(self.render_bytes(camera, downscale=downscale))

    def render_depth(
        self, camera: PinholeCamera | dict[str, Any], *, downscale: int = 1
    ) -> np.ndarray:
        """View-space depth as an (H, W) float32 array, 0 where empty (``images`` extra)."""
        return media.decode_array(self.render_bytes(camera, "npy", downscale=downscale))

    def render_to(
        self,
        camera: PinholeCamera | dict[str, Any],
        path: str | Path,
        *,
        output: RenderOutput | None = None,
        downscale: int = 1,
    ) -> Path:
        """Render into a file; the output follows the suffix (.png .jpg .webp .npy)."""
        path = Path(path)
        data = self.render_bytes(camera, _output_for(path, output), downscale=downscale)
        return _write(path, data)

    def render_path_bytes(
        self,
        cameras: Sequence[PinholeCamera | dict[str, Any]],
        output: RenderOutput = "png",
        *,
        downscale: int = 1,
        quality: int = 90,
    ) -> list[bytes]:
        """Every camera of a path rendered in one request: the encoded frames, in order."""
        call = self.client._c_render(self.id, None, cameras, output, downscale, quality)
        return _unzip(self.client._send(call))

    def render_path(
        self, cameras: Sequence[PinholeCamera | dict[str, Any]], *, downscale: int = 1
    ) -> list[np.ndarray]:
        """A camera path as (H, W, 3) uint8 arrays (``images`` extra)."""
        frames = self.render_path_bytes(cameras, downscale=downscale)
        return [media.decode_array(f) for f in frames]

    def render_path_to(
        self,
        cameras: Sequence[PinholeCamera | dict[str, Any]],
        folder: str | Path,
        output: RenderOutput = "png",
        *,
        downscale: int = 1,
    ) -> list[Path]:
        """A camera path written as numbered files ``0000.png``… into ``folder``."""
        frames = self.render_path_bytes(cameras, output, downscale=downscale)
        return _write_frames(folder, frames, output)

    def orbit(
        self,
        n: int = 60,
        *,
        intrinsics: cams.Intrinsics | None = None,
        radius_scale: float = 1.0,
        arc_deg: float = 360.0,
        elevation_deg: float | None = None,
    ) -> list[PinholeCamera]:
        """A camera orbit fitted to the model's training cameras (see
        :func:`~sparsesplat.client.cameras.orbit_around`)."""
        return cams.orbit_around(
            self.cameras("train"),
            n,
            intrinsics=intrinsics,
            radius_scale=radius_scale,
            arc_deg=arc_deg,
            elevation_deg=elevation_deg,
        )

    def video(
        self,
        cameras: Sequence[PinholeCamera | dict[str, Any]],
        path: str | Path,
        *,
        fps: float = 30.0,
        downscale: int = 1,
    ) -> Path:
        """Render a camera path and encode it as a video (.mp4…; ``video`` extra)."""
        media.require("imageio", "writing a video")
        return media.write_video(self.render_path_bytes(cameras, downscale=downscale), path, fps)

    def export(self, format: ExportFormat, path: str | Path) -> Path:
        """Download the model as ``ply`` (INRIA layout), ``splat`` or ``checkpoint``."""
        return _write(path, self.client._send(self.client._c_export(self.id, format)))

    def __repr__(self) -> str:
        return f"ModelHandle({self.id!r})"


# ==================================================================== asyncio


class AsyncClient(_Base):
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
        self._http = httpx.AsyncClient(
            base_url=self.base_url,
            headers=self._headers,
            timeout=self._timeout(self.timeouts.read),
            transport=transport,
        )

    async def _send(self, call: _Call[T]) -> T:
        attempt = 1
        while True:
            try:
                try:
                    response = await self._http.request(
                        call.method, call.path, **self._request_args(call)
                    )
                except httpx.TransportError as exc:
                    raise self._transport_error(call, exc) from exc
                return self._finish(call, response, attempt)
            except (APIError, ConnectionFailed, Timeout) as exc:
                wait = self._should_retry(call, attempt, exc)
                if wait is None:
                    raise
            await asyncio.sleep(wait)
            attempt += 1

    async def health(self) -> Health:
        """``GET /healthz``."""
        return await self._send(self._c_health())

    async def ready(self) -> Readiness:
        """``GET /readyz``."""
        return await self._send(self._c_ready())

    async def submit(
        self,
        upload: Upload,
        spec: JobSpec | dict[str, Any] | None = None,
        *,
        idempotency_key: IdempotencyKey = "auto",
    ) -> AsyncJobHandle:
        """See :meth:`Client.submit`."""
        job = await self._send(self._c_submit(upload, spec, idempotency_key))
        return AsyncJobHandle(self, job, upload)

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
        upload = await asyncio.to_thread(
            read_scene, path, views=views, test_views=test_views, downscale=downscale,
            format=format,
        )  # fmt: skip
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

    async def metrics(self, job_id: str) -> list[Record]:
        """See :meth:`Client.metrics`."""
        return await self._send(self._c_metrics(job_id))

    async def events(
        self, job_id: str, after: int = 0, *, timeout: float | None = None
    ) -> AsyncIterator[Event]:
        """See :meth:`Client.events`."""
        from websockets.asyncio.client import connect
        from websockets.exceptions import ConnectionClosed, InvalidStatus, WebSocketException

        deadline = None if timeout is None else time.monotonic() + timeout
        last, lost_since, attempt = after, None, 0
        while True:
            try:
                async with connect(
                    self._ws_url(job_id, last),
                    additional_headers=self._headers,
                    open_timeout=self.timeouts.connect,
                    close_timeout=2,
                ) as ws:
                    lost_since, attempt = None, 0
                    while True:
                        wait = self.timeouts.event_idle
                        if deadline is not None:
                            wait = min(wait, deadline - time.monotonic())
                            if wait <= 0:
                                raise Timeout(f"job {job_id}: no end within {timeout} s")
                        try:
                            message = await asyncio.wait_for(ws.recv(), wait)
                        except TimeoutError:
                            if deadline is not None and time.monotonic() >= deadline:
                                raise Timeout(f"job {job_id}: no end within {timeout} s") from None
                            break
                        event = Event.model_validate_json(message)
                        if event.seq <= last:
                            continue
                        last = event.seq
                        yield event
                        if _terminal(event):
                            return
            except SparsesplatError:
                raise
            except ConnectionClosed as exc:
                code = exc.rcvd.code if exc.rcvd is not None else None
                failure = _ws_failure(code, exc.rcvd.reason if exc.rcvd else "", job_id)
                if failure is not None:
                    raise failure from exc
                if code == 1000 and (await self.get_job(job_id)).state.terminal:
                    return
            except InvalidStatus as exc:
                await self.get_job(job_id)
                raise ServerError(
                    exc.response.status_code, "events_refused", f"event stream refused: {exc}"
                ) from exc
            except (OSError, WebSocketException) as exc:
                lost_since = lost_since or time.monotonic()
                if time.monotonic() - lost_since > self.retry.reconnect_s:
                    raise ConnectionFailed(
                        f"lost the event stream of job {job_id} at {self.base_url}: {exc}"
                    ) from exc
            attempt += 1
            await asyncio.sleep(self.retry.delay(min(attempt, 5)))

    def model(self, model_id: str) -> AsyncModelHandle:
        """See :meth:`Client.model`."""
        return AsyncModelHandle(self, model_id)

    async def aclose(self) -> None:
        """Close the connection pool."""
        await self._http.aclose()

    async def __aenter__(self) -> AsyncClient:
        return self

    async def __aexit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        tb: TracebackType | None,
    ) -> None:
        await self.aclose()


class AsyncJobHandle:
    """asyncio twin of :class:`JobHandle`."""

    def __init__(self, client: AsyncClient, info: Job, upload: Upload | None = None) -> None:
        self.client = client
        self.info = info
        """The job record as last read."""
        self.upload = upload
        """What was submitted (when this handle came from a submission)."""

    @property
    def id(self) -> str:
        """Job id (also its model's)."""
        return self.info.id

    @property
    def state(self) -> JobState:
        """State as last read."""
        return self.info.state

    async def refresh(self) -> Job:
        """See :meth:`JobHandle.refresh`."""
        self.info = await self.client.get_job(self.id)
        return self.info

    def events(self, after: int = 0, *, timeout: float | None = None) -> AsyncIterator[Event]:
        """See :meth:`JobHandle.events`."""
        return self.client.events(self.id, after, timeout=timeout)

    async def wait(
        self,
        timeout: float | None = None,
        *,
        progress: bool | None = None,
        callback: EventCallback | None = None,
        raise_on_failure: bool = True,
    ) -> Job:
        """See :meth:`JobHandle.wait`; ``callback`` may also be a coroutine function."""
        bar = ProgressBar(self.id, progress)
        try:
            async for event in self.events(timeout=timeout):
                bar.update(event)
                if callback is not None:
                    result = callback(event)
                    if asyncio.iscoroutine(result):
                        await result
        finally:
            bar.close()
        job = await self.refresh()
        warn_about(job)
        if raise_on_failure and job.state != JobState.succeeded:
            raise JobFailed(job)
        return job

    async def metrics(self) -> list[Record]:
        """See :meth:`JobHandle.metrics`."""
        return await self.client.metrics(self.id)

    async def metrics_frame(self) -> pd.DataFrame:
        """See :meth:`JobHandle.metrics_frame`."""
        return _frame(await self.metrics())

    async def metrics_plot(self, path: str | Path) -> Path:
        """See :meth:`JobHandle.metrics_plot`."""
        return _write(path, await self.client._send(self.client._c_metrics_plot(self.id)))

    async def cancel(self) -> Job:
        """See :meth:`JobHandle.cancel`."""
        self.info = await self.client.cancel(self.id)
        return self.info

    async def delete(self) -> None:
        """See :meth:`JobHandle.delete`."""
        await self.client.delete(self.id)

    @property
    def model(self) -> AsyncModelHandle:
        """See :attr:`JobHandle.model`."""
        return AsyncModelHandle(self.client, self.id)

    def __repr__(self) -> str:
        return f"AsyncJobHandle({self.id!r}, state={self.state.value!r})"


class AsyncModelHandle:
    """asyncio twin of :class:`ModelHandle`."""

    def __init__(self, client: AsyncClient, model_id: str) -> None:
        self.client = client
        self.id = model_id
        """Model id (= the job id)."""

    async def info(self) -> ModelInfo:
        """See :meth:`ModelHandle.info`."""
        return await self.client._send(self.client._c_model(self.id))

    async def cameras(self, split: str | None = "train") -> list[PinholeCamera]:
        """See :meth:`ModelHandle.cameras`."""
        return _model_cameras(await self.info(), split)

    async def render_bytes(
        self,
        camera: PinholeCamera | dict[str, Any],
        output: RenderOutput = "png",
        *,
        downscale: int = 1,
        quality: int = 90,
    ) -> bytes:
        """See :meth:`ModelHandle.render_bytes`."""
        call = self.client._c_render(self.id, camera, None, output, downscale, quality)
        return await self.client._send(call)

    async def render(
        self, camera: PinholeCamera | dict[str, Any], *, downscale: int = 1
    ) -> np.ndarray:
        """See :meth:`ModelHandle.render`."""
        return media.decode_array(await self.render_bytes(camera, downscale=downscale))

    async def render_image(
        self, camera: PinholeCamera | dict[str, Any], *, downscale: int = 1
    ) -> Image.Image:
        """See :meth:`ModelHandle.render_image`."""
        return media.decode_image(await self.render_bytes(camera, downscale=downscale))

    async def render_depth(
        self, camera: PinholeCamera | dict[str, Any], *, downscale: int = 1
    ) -> np.ndarray:
        """See :meth:`ModelHandle.render_depth`."""
        return media.decode_array(await self.render_bytes(camera, "npy", downscale=downscale))

    async def render_to(
        self,
        camera: PinholeCamera | dict[str, Any],
        path: str | Path,
        *,
        output: RenderOutput | None = None,
        downscale: int = 1,
    ) -> Path:
        """See :meth:`ModelHandle.render_to`."""
        path = Path(path)
        data = await self.render_bytes(camera, _output_for(path, output), downscale=downscale)
        return _write(path, data)

    async def render_path_bytes(
        self,
        cameras: Sequence[PinholeCamera | dict[str, Any]],
        output: RenderOutput = "png",
        *,
        downscale: int = 1,
        quality: int = 90,
    ) -> list[bytes]:
        """See :meth:`ModelHandle.render_path_bytes`."""
        call = self.client._c_render(self.id, None, cameras, output, downscale, quality)
        return _unzip(await self.client._send(call))

    async def render_path(
        self, cameras: Sequence[PinholeCamera | dict[str, Any]], *, downscale: int = 1
    ) -> list[np.ndarray]:
        """See :meth:`ModelHandle.render_path`."""
        frames = await self.render_path_bytes(cameras, downscale=downscale)
        return [media.decode_array(f) for f in frames]

    async def render_path_to(
        self,
        cameras: Sequence[PinholeCamera | dict[str, Any]],
        folder: str | Path,
        output: RenderOutput = "png",
        *,
        downscale: int = 1,
    ) -> list[Path]:
        """See :meth:`ModelHandle.render_path_to`."""
        frames = await self.render_path_bytes(cameras, output, downscale=downscale)
        return _write_frames(folder, frames, output)

    async def orbit(
        self,
        n: int = 60,
        *,
        intrinsics: cams.Intrinsics | None = None,
        radius_scale: float = 1.0,
        arc_deg: float = 360.0,
        elevation_deg: float | None = None,
    ) -> list[PinholeCamera]:
        """See :meth:`ModelHandle.orbit`."""
        return cams.orbit_around(
            await self.cameras("train"),
            n,
            intrinsics=intrinsics,
            radius_scale=radius_scale,
            arc_deg=arc_deg,
            elevation_deg=elevation_deg,
        )

    async def video(
        self,
        cameras: Sequence[PinholeCamera | dict[str, Any]],
        path: str | Path,
        *,
        fps: float = 30.0,
        downscale: int = 1,
    ) -> Path:
        """See :meth:`ModelHandle.video`."""
        media.require("imageio", "writing a video")
        frames = await self.render_path_bytes(cameras, downscale=downscale)
        return await asyncio.to_thread(media.write_video, frames, path, fps)

    async def export(self, format: ExportFormat, path: str | Path) -> Path:
        """See :meth:`ModelHandle.export`."""
        return _write(path, await self.client._send(self.client._c_export(self.id, format)))

    def __repr__(self) -> str:
        return f"AsyncModelHandle({self.id!r})"


# ==================================================================== shared helpers


def _write(path: str | Path, data: bytes) -> Path:
    """Write ``data`` to ``path`` atomically (a partial file never has the final name)."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(f".{path.name}.part")
    tmp.write_bytes(data)
    tmp.replace(path)
    return path


def _write_frames(folder: str | Path, frames: list[bytes], output: RenderOutput) -> list[Path]:
    suffix = {"jpeg": "jpg", "depth16": "png", "alpha": "png"}.get(output, output)
    return [_write(Path(folder) / f"{i:04d}.{suffix}", f) for i, f in enumerate(frames)]


def _frame(records: list[Record]) -> pd.DataFrame:
    pandas = media.require("pandas", "metrics as a DataFrame")
    frame: pd.DataFrame = pandas.DataFrame(
        [r.model_dump() for r in records], columns=list(Record.model_fields)
    )
    return frame


def _model_cameras(info: ModelInfo, split: str | None) -> list[PinholeCamera]:
    out = []
    for frame in info.cameras:
        if split is not None and frame.get("split", "train") != split:
            continue
        out.append(
            PinholeCamera.model_validate(
                {k: frame[k] for k in PinholeCamera.model_fields if k in frame}
            )
        )
    return out
