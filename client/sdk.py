"""Sync and async clients as twins over one base that builds requests and parses answers.

Both accept an injectable ``transport`` (httpx), so tests and embedders can route requests
anywhere without a network.
"""

from __future__ import annotations

import os
from types import TracebackType
from typing import Any, TypeVar

import httpx
from pydantic import BaseModel

from sparsesplat.api.schemas import ErrorBody, Health
from sparsesplat.client.errors import ConnectionFailed, error_for_status

DEFAULT_URL = "http://127.0.0.1:8000"
URL_ENV = "SPARSESPLAT_URL"
API_KEY_ENV = "SPARSESPLAT_API_KEY"

ModelT = TypeVar("ModelT", bound=BaseModel)


class _Base:
    """What both clients share: base URL, auth header, timeouts, answer parsing."""

    def __init__(
        self, base_url: str | None = None, api_key: str | None = None, timeout: float = 30.0
    ) -> None:
        self.base_url = (base_url or os.environ.get(URL_ENV) or DEFAULT_URL).rstrip("/")
        key = api_key if api_key is not None else os.environ.get(API_KEY_ENV)
        self._headers = {"Authorization": f"Bearer {key}"} if key else {}
        self._timeout = timeout

    @staticmethod
    def _parse(response: httpx.Response, model: type[ModelT]) -> ModelT:
        if response.is_success:
            return model.model_validate_json(response.content)
        try:
            body = ErrorBody.model_validate_json(response.content)
            code, message = body.code, body.message
        except ValueError:
            code, message = f"http_{response.status_code}", response.text[:500]
        raise error_for_status(response.status_code, code, message)


class Client(_Base):
    """Blocking client. Use as a context manager or call :meth:`close`."""

    def __init__(
        self,
        base_url: str | None = None,
        api_key: str | None = None,
        timeout: float = 30.0,
        transport: httpx.BaseTransport | None = None,
    ) -> None:
        super().__init__(base_url, api_key, timeout)
        self._http = httpx.Client(
            base_url=self.base_url, headers=self._headers, timeout=timeout, transport=transport
        )

    def _request(self, method: str, path: str, **kwargs: Any) -> httpx.Response:
        try:
            return self._http.request(method, path, **kwargs)
        except httpx.TransportError as exc:
            raise ConnectionFailed(f"cannot reach {self.base_url}{path}: {exc}") from exc

    def health(self) -> Health:
        """``GET /healthz``."""
        return self._parse(self._request("GET", "/healthz"), Health)

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


class AsyncClient(_Base):
    """asyncio twin of :class:`Client` with the same methods as coroutines."""

    def __init__(
        self,
        base_url: str | None = None,
        api_key: str | None = None,
        timeout: float = 30.0,
        transport: httpx.AsyncBaseTransport | None = None,
    ) -> None:
        super().__init__(base_url, api_key, timeout)
        self._http = httpx.AsyncClient(
            base_url=self.base_url, headers=self._headers, timeout=timeout, transport=transport
        )

    async def _request(self, method: str, path: str, **kwargs: Any) -> httpx.Response:
        try:
            return await self._http.request(method, path, **kwargs)
        except httpx.TransportError as exc:
            raise ConnectionFailed(f"cannot reach {self.base_url}{path}: {exc}") from exc

    async def health(self) -> Health:
        """``GET /healthz``."""
        return self._parse(await self._request("GET", "/healthz"), Health)

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
