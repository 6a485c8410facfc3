"""The service's error answers: ``{code, message}`` with the right status."""

from __future__ import annotations

from fastapi import HTTPException


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
