"""The service's error answers: ``{code, message}`` with the right status."""

from __future__ import annotations

from fastapi import HTTPException
from pydantic import ValidationError

CLOSE_NOT_FOUND = 4404
"""WebSocket close code: no such job or model (or another key's)."""
CLOSE_UNAUTHENTICATED = 4401
"""WebSocket close code: missing or unknown API key."""


class ServiceError(HTTPException):
    """An HTTP error with a stable ``code`` and a message naming the problem."""

    def __init__(
        self, status: int, code: str, message: str, headers: dict[str, str] | None = None
    ) -> None:
        """Error ``code`` answered with ``status``."""
        super().__init__(status_code=status, detail=message, headers=headers)
        self.code = code


def not_found(what: str, ident: str) -> ServiceError:
    """404 for a job or model that does not exist (or belongs to another key)."""
    return ServiceError(404, f"{what}_not_found", f"no {what} {ident!r}")


def invalid(code: str, message: str) -> ServiceError:
    """422: the request is well-formed HTTP but its content is wrong."""
    return ServiceError(422, code, message)


def pydantic_message(exc: ValidationError, prefix: str) -> str:
    """One line naming each problem's location and what is wrong."""
    parts = []
    for err in exc.errors():
        loc = ".".join(str(p) for p in err.get("loc", ()))
        msg = str(err.get("msg", "")).removeprefix("Value error, ")
        if err.get("type") == "enum":  # say what was sent, as the schema's own messages do
            msg = f"{msg}, got {err.get('input')!r}"
        parts.append(f"{prefix}{'.' + loc if loc else ''}: {msg}")
    return "; ".join(parts)
