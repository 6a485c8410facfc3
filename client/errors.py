"""One exception class per failure kind, so callers can catch exactly what they handle."""

from __future__ import annotations


class SparsesplatError(Exception):
    """Base class of every SDK error."""


class ConnectionFailed(SparsesplatError):
    """The server could not be reached (refused, DNS, timeout)."""


class APIError(SparsesplatError):
    """The server answered with an error status; ``code`` and ``message`` come from its body."""

    def __init__(self, status: int, code: str, message: str) -> None:
        super().__init__(f"HTTP {status} {code}: {message}")
        self.status = status
        self.code = code
        self.message = message


class AuthenticationError(APIError):
    """401/403: missing or wrong API key."""


class NotFound(APIError):
    """404: no such job, model or route."""


class ValidationFailed(APIError):
    """400/409/413/422: the request was malformed; ``message`` names the problem."""


class ServerError(APIError):
    """5xx: the server failed."""


def error_for_status(status: int, code: str, message: str) -> APIError:
    """The most specific :class:`APIError` subclass for an HTTP status."""
    if status in (401, 403):
        return AuthenticationError(status, code, message)
    if status == 404:
        return NotFound(status, code, message)
    if status >= 500:
        return ServerError(status, code, message)
    if status >= 400:
        return ValidationFailed(status, code, message)
    return APIError(status, code, message)
