"""One exception class per failure kind, so callers catch exactly what they handle.

::

    SparsesplatError
    ├── ConnectionFailed      the server could not be reached (also a builtin ConnectionError)
    ├── Timeout               a request, or wait(timeout=...), ran out of time (a TimeoutError)
    ├── MissingExtra          the call needs an optional dependency (an ImportError)
    ├── InvalidInput          refused before sending: a scene folder, image or camera is wrong
    ├── JobFailed             wait() saw the job end failed or cancelled (``job`` attached)
    └── APIError              the server answered with an error status (``status, code, message``)
        ├── AuthenticationError   401/403: missing, unknown or revoked API key
        ├── NotFound              404: no such job or model (another key's counts as none)
        ├── ValidationFailed      400/413/422: the server's message names the field or file
        ├── Conflict              409: e.g. a model asked for before its job succeeded
        ├── RateLimited           429: ``retry_after`` seconds to wait
        └── ServerError           5xx (``ServiceUnavailable`` for 503, with ``retry_after``)

The CLI maps each kind to its own exit code (:data:`EXIT_CODES`).
"""

from __future__ import annotations

from typing import TYPE_CHECKING

if TYPE_CHECKING:
    from sparsesplat.api.jobs import Job


class SparsesplatError(Exception):
    """Base class of every SDK error."""


class ConnectionFailed(SparsesplatError, ConnectionError):
    """The server could not be reached: refused, DNS, reset, or it stopped mid-answer."""


class Timeout(SparsesplatError, TimeoutError):
    """A request took longer than its timeout, or ``wait(timeout=...)`` expired."""


class MissingExtra(SparsesplatError, ImportError):
    """An optional dependency is missing; the message names the extra to install."""

    def __init__(self, module: str, extra: str, what: str) -> None:
        super().__init__(
            f"{what} needs the '{extra}' extra (missing module {module!r}). "
            f"Install it with: pip install 'sparsesplat[{extra}]'"
        )
        self.module = module
        self.extra = extra


class InvalidInput(SparsesplatError, ValueError):
    """Refused on this side before anything was sent (a scene folder, image or camera)."""


class JobFailed(SparsesplatError):
    """A waited-for job ended ``failed`` or ``cancelled``; ``job`` is its final record."""

    def __init__(self, job: Job) -> None:
        reason = f": {job.error}" if job.error else ""
        super().__init__(f"job {job.id} {job.state.value}{reason}")
        self.job = job


class JobWarning(UserWarning):
    """Issued (``warnings.warn``) when a waited-for job ends with warnings on its record:
    training found something wrong the upload could not show, e.g. held-out renders that stay
    empty (usually poses read the wrong way). The job may still have succeeded."""


def warn_about(job: Job, stacklevel: int = 3) -> None:
    """One :class:`JobWarning` per warning on ``job``'s record (``stacklevel`` as in
    :func:`warnings.warn`, counted from this function: 3 names its caller's caller)."""
    import warnings

    for message in job.warnings:
        warnings.warn(f"job {job.id}: {message}", JobWarning, stacklevel=stacklevel)


class RenderWarning(UserWarning):
    """Issued when a render sees (nearly) nothing of the model (the service's
    ``X-Render-Warning`` header): the camera is likely read the wrong way, far away or
    facing away from the scene."""


class APIError(SparsesplatError):
    """The server answered with an error status; ``code`` and ``message`` come from its body."""

    def __init__(
        self, status: int, code: str, message: str, retry_after: float | None = None
    ) -> None:
        super().__init__(f"HTTP {status} {code}: {message}")
        self.status = status
        """HTTP status."""
        self.code = code
        """Stable error code from the server (e.g. ``invalid_cameras``, ``job_not_found``)."""
        self.message = message
        """The server's sentence naming the problem."""
        self.retry_after = retry_after
        """Seconds the server asked to wait (``Retry-After``), when it said."""


class AuthenticationError(APIError):
    """401/403: missing, unknown or revoked API key."""


class NotFound(APIError):
    """404: no such job, model or route (another key's job is reported as absent)."""


class ValidationFailed(APIError):
    """400/413/422: the request was refused; ``message`` names the field or file."""


class Conflict(APIError):
    """409: the resource is not in a state for this call (a model before its job succeeded)."""


class RateLimited(APIError):
    """429: too many requests (renders per second, or active jobs); wait ``retry_after``."""


class ServerError(APIError):
    """5xx: the server failed."""


class ServiceUnavailable(ServerError):
    """503: no worker, or the database is not answering; try again after ``retry_after``."""


def error_for_status(
    status: int, code: str, message: str, retry_after: float | None = None
) -> APIError:
    """The most specific :class:`APIError` subclass for an HTTP status."""
    kind: type[APIError] = APIError
    if status in (401, 403):
        kind = AuthenticationError
    elif status == 404:
        kind = NotFound
    elif status == 409:
        kind = Conflict
    elif status == 429:
        kind = RateLimited
    elif status == 503:
        kind = ServiceUnavailable
    elif status >= 500:
        kind = ServerError
    elif status >= 400:
        kind = ValidationFailed
    return kind(status, code, message, retry_after)


EXIT_CODES: dict[type[BaseException], int] = {
    JobFailed: 1,
    ValidationFailed: 2,
    InvalidInput: 2,
    MissingExtra: 3,
    NotFound: 4,
    AuthenticationError: 5,
    Conflict: 6,
    RateLimited: 7,
    ServerError: 8,
    ConnectionFailed: 9,
    Timeout: 10,
}
"""CLI exit status for each error kind (see docs/sdk.md); other SDK errors exit 1."""


def exit_code(exc: BaseException) -> int:
    """The CLI exit status for ``exc`` (most specific class first)."""
    for kind in type(exc).__mro__:
        if kind in EXIT_CODES:
            return EXIT_CODES[kind]
    return 1
