"""The transport-free half of both clients: request descriptions (:class:`_Call`), answer
decoding, error mapping and retry decisions, and every API call built once in :class:`_Base`.
The sync and async clients add only the I/O."""

from __future__ import annotations

import json
import os
import uuid
import warnings
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import Any, Generic, TypeVar, get_args
from urllib.parse import urlencode

import httpx
from pydantic import BaseModel, TypeAdapter, ValidationError

from sparsesplat.api.cameras import PinholeCamera
from sparsesplat.api.jobs import Job, JobPage, JobSpec, JobState, ModelInfo, Record
from sparsesplat.api.names import ExportFormat
from sparsesplat.api.renders import RENDER_WARNING_HEADER, RenderMode, RenderOutput
from sparsesplat.api.schemas import ErrorBody, Health, Readiness
from sparsesplat.api.usage import Usage
from sparsesplat.client import media
from sparsesplat.client.errors import (
    APIError,
    ConnectionFailed,
    InvalidInput,
    RenderWarning,
    ServerError,
    Timeout,
    error_for_status,
)
from sparsesplat.client.photos import Photos
from sparsesplat.client.scenes import Upload
from sparsesplat.client.sdk._config import (
    API_KEY_ENV,
    DEFAULT_RETRY,
    DEFAULT_TIMEOUTS,
    DEFAULT_URL,
    URL_ENV,
    IdempotencyKey,
    RetryPolicy,
    Timeouts,
)

T = TypeVar("T")
ModelT = TypeVar("ModelT", bound=BaseModel)
_RECORDS = TypeAdapter(list[Record])


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
        # stacklevel 5: past this parser, _finish, _Attempts.read and _send, to the handle
        # that sent the call.
        warnings.warn(f"render: {message}", RenderWarning, stacklevel=5)
    return response.content


def _nothing(response: httpx.Response) -> None:
    return None


def _records(response: httpx.Response) -> list[Record]:
    return _RECORDS.validate_json(response.content)


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


class _Attempts(Generic[T]):
    """One call's tries, without I/O: :meth:`read` takes what a try gave (the answer, or the
    transport's error) and says how long to wait before the next try, or None once
    :attr:`result` holds the decoded answer. An error that is not retried is raised. The
    clients' ``_send`` only makes the tries and waits."""

    result: T
    """The decoded answer (set when :meth:`read` returns None)."""

    def __init__(self, client: _Base, call: _Call[T]) -> None:
        self.client = client
        self.call = call
        self.number = 1
        """The try being read (1: the first)."""

    def read(self, outcome: httpx.Response | httpx.TransportError) -> float | None:
        """Seconds to wait before trying again, or None when :attr:`result` is set."""
        try:
            if isinstance(outcome, httpx.TransportError):
                raise self.client._transport_error(self.call, outcome) from outcome
            self.result = self.client._finish(self.call, outcome, self.number)
            return None
        except (APIError, ConnectionFailed, Timeout) as exc:
            wait = self.client._should_retry(self.call, self.number, exc)
            if wait is None:
                raise
        self.number += 1
        return wait


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

    def _http_options(self, transport: Any) -> dict[str, Any]:
        """The keywords of either client's httpx client (``transport``: its own kind)."""
        return {
            "base_url": self.base_url,
            "headers": self._headers,
            "timeout": self._timeout(self.timeouts.read),
            "transport": transport,
        }

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

    def _ws_base(self) -> str:
        """The base URL with its scheme made ``ws`` / ``wss``."""
        base = self.base_url
        scheme = "wss" if base.startswith("https") else "ws"
        return f"{scheme}{base[base.index(':') :]}"

    def _ws_url(self, job_id: str, after: int) -> str:
        query = urlencode({"after": after})
        return f"{self._ws_base()}/v1/jobs/{job_id}/events?{query}"

    def _ws_options(self) -> dict[str, Any]:
        """The keywords of every WebSocket the clients open (events, the live view)."""
        return {
            "additional_headers": dict(self._headers),
            "open_timeout": self.timeouts.connect,
            "close_timeout": 2,
        }

    def _live_url(self, model_id: str) -> str:
        return f"{self._ws_base()}/v1/models/{model_id}/live"

    # ------------------------------------------------------------ calls

    def _c_health(self) -> _Call[Health]:
        return _Call("GET", "/healthz", _model(Health), self.timeouts.read, True)

    def _c_ready(self) -> _Call[Readiness]:
        return _Call(
            "GET", "/readyz", _model(Readiness), self.timeouts.read, True, ok_statuses=(503,)
        )

    def _c_submit(
        self,
        upload: Upload | Photos,
        spec: JobSpec | dict[str, Any] | None,
        idempotency_key: IdempotencyKey,
    ) -> _Call[Job]:
        upload.validate()
        files: list[tuple[str, tuple[str, bytes, str]]] = []
        form = {"spec": _spec_json(spec, upload.preset)}
        if isinstance(upload, Photos):  # no cameras: the service estimates them
            if upload.intrinsics is not None:
                form["intrinsics"] = upload.intrinsics.model_dump_json(exclude_none=True)
        else:
            document = json.dumps(upload.cameras).encode()
            files.append(("cameras", ("cameras.json", document, "application/json")))
        for name, data in upload.images.items():
            kind = media.sniff(data) or "png"
            files.append(("images", (name, data, media.UPLOAD_FORMATS[kind])))
        if isinstance(upload, Upload):
            for name, data in upload.depths.items():
                files.append(("depths", (name, data, "application/octet-stream")))
            for name, data in upload.masks.items():
                kind = media.sniff(data) or "png"
                files.append(("masks", (name, data, media.UPLOAD_FORMATS[kind])))
        key = uuid.uuid4().hex if idempotency_key == "auto" else idempotency_key
        return _Call(
            "POST",
            "/v1/jobs",
            _model(Job),
            self.timeouts.upload,
            idempotent=key is not None,
            files=files,
            data=form,
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
        mode: RenderMode,
    ) -> _Call[bytes]:
        body: dict[str, Any] = {
            "output": output,
            "downscale": downscale,
            "quality": quality,
            "mode": mode,
        }
        timeout = self.timeouts.render
        if path is not None:
            body["path"] = [_camera_json(c) for c in path]
            timeout = min(self.timeouts.render * max(1, len(path)), self.timeouts.download)
        else:
            body["camera"] = _camera_json(camera) if camera is not None else None
        return _Call(
            "POST", f"/v1/models/{model_id}/render", _render_content, timeout, True, json=body
        )

    def _c_pin(self, model_id: str, pinned: bool) -> _Call[ModelInfo]:
        method = "PUT" if pinned else "DELETE"
        path = f"/v1/models/{model_id}/pin"
        return _Call(method, path, _model(ModelInfo), self.timeouts.read, True)

    def _c_usage(self) -> _Call[Usage]:
        return _Call("GET", "/v1/usage", _model(Usage), self.timeouts.read, True)

    def _c_export(self, model_id: str, format: ExportFormat) -> _Call[bytes]:
        if format not in get_args(ExportFormat):
            raise InvalidInput(f"export format {format!r}: use 'ply', 'splat' or 'checkpoint'")
        return _Call(
            "GET", f"/v1/models/{model_id}/export/{format}", _content, self.timeouts.download, True
        )
