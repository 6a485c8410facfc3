"""Sends validated render requests to the render workers registered in the database.

A model always goes to the same live worker (its id hashed over the sorted worker list), so
each model is loaded in one worker's cache rather than in all of them.
"""

from __future__ import annotations

import asyncio
import hashlib
import time

import httpx

from sparsesplat.api.renders import RenderRequest
from sparsesplat.api.store.workers import WorkerInfo, WorkerRegistry

WORKER_LIST_TTL_S = 2.0
"""How long the list of live render workers is reused before it is read again."""
MAX_CONNECTIONS = 8
"""Open connections from one API process to the render workers."""
RENDER_TIMEOUT_S = 120.0
"""Longest a render may take (a long camera path at full size)."""


class NoRenderWorker(RuntimeError):
    """No render worker has sent a heartbeat recently."""


class RenderFailed(RuntimeError):
    """A render worker answered with an error; ``status`` is its HTTP status."""

    def __init__(self, status: int, message: str) -> None:
        """Failure with the worker's ``status`` and message."""
        super().__init__(message)
        self.status = status


class RenderDispatcher:
    """Routes each model's renders to one live render worker."""

    def __init__(self, registry: WorkerRegistry, max_age_s: float = 30.0) -> None:
        """Workers are looked up in ``registry``; stale after ``max_age_s`` without a beat."""
        self.registry = registry
        self.max_age_s = max_age_s
        # A worker renders one request at a time: a few connections keep it busy, and the
        # rest of a burst waits in this pool instead of piling up in the worker's accept queue.
        self._http = httpx.AsyncClient(
            timeout=RENDER_TIMEOUT_S, limits=httpx.Limits(max_connections=MAX_CONNECTIONS)
        )
        self._workers: list[WorkerInfo] = []
        self._read_at = 0.0

    async def _live(self) -> list[WorkerInfo]:
        if time.monotonic() - self._read_at > WORKER_LIST_TTL_S or not self._workers:
            workers = await asyncio.to_thread(self.registry.live, "render", self.max_age_s)
            self._workers = [w for w in workers if w.address]
            self._read_at = time.monotonic()
        return self._workers

    async def render(self, model_id: str, request: RenderRequest) -> httpx.Response:
        """The worker's answer (200 with the bytes); raises NoRenderWorker / RenderFailed."""
        workers = await self._live()
        if not workers:
            raise NoRenderWorker("no render worker is running; start one with 'sparsesplat worker'")
        index = int(hashlib.sha256(model_id.encode()).hexdigest(), 16) % len(workers)
        body = {"model_id": model_id, "request": request.model_dump(mode="json")}
        try:
            response = await self._http.post(f"http://{workers[index].address}/render", json=body)
        except httpx.TransportError as exc:
            self._read_at = 0.0  # the worker may have gone: read the list again next time
            raise NoRenderWorker(f"render worker at {workers[index].address} unreachable") from exc
        if response.status_code != 200:
            try:
                message = response.json().get("message", response.text)
            except ValueError:
                message = response.text
            raise RenderFailed(response.status_code, message)
        return response

    async def close(self) -> None:
        """Close connections to the workers."""
        await self._http.aclose()
