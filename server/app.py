"""FastAPI application factory. Routes stay thin; state lives on ``app.state``, never in modules."""

from __future__ import annotations

import asyncio
import contextlib
import logging
from collections.abc import AsyncIterator
from contextlib import asynccontextmanager

import sqlalchemy.exc
from fastapi import FastAPI, Request
from fastapi.exceptions import RequestValidationError
from fastapi.responses import JSONResponse
from fastapi.routing import APIRoute
from starlette.exceptions import HTTPException as StarletteHTTPException

from sparsesplat import __version__
from sparsesplat.api.artifacts import ArtifactMissing, ArtifactStoreError
from sparsesplat.api.disk import disk_full_message, free_bytes, is_disk_full
from sparsesplat.api.schemas import ErrorBody
from sparsesplat.api.settings import Settings, load_settings
from sparsesplat.server.auth import Authenticator
from sparsesplat.server.errors import ServiceError
from sparsesplat.server.expiry import sweep_forever
from sparsesplat.server.limits import BodySizeLimit
from sparsesplat.server.routes import events, jobs, live, models, pages, service, usage
from sparsesplat.server.state import ServiceState

log = logging.getLogger("sparsesplat.server")
# httpx logs every request to the render workers at INFO; uvicorn's access log already has them.
logging.getLogger("httpx").setLevel(logging.WARNING)

_STATUS_CODES = {400: "bad_request", 404: "not_found", 405: "method_not_allowed"}


def _operation_id(route: APIRoute) -> str:
    """Stable OpenAPI operation ids (``tag-name``) so generated clients keep their names."""
    tag = route.tags[0] if route.tags else "default"
    return f"{tag}-{route.name}"


def _error(
    status: int, code: str, message: str, headers: dict[str, str] | None = None
) -> JSONResponse:
    return JSONResponse(ErrorBody(code=code, message=message).model_dump(), status, headers)


def create_app(settings: Settings | None = None) -> FastAPI:
    """Build the application for ``settings`` (default: read from the environment)."""
    settings = settings or load_settings()

    @asynccontextmanager
    async def lifespan(app: FastAPI) -> AsyncIterator[None]:
        state = ServiceState.open(settings)
        app.state.service = state
        app.state.authenticator = Authenticator(settings, state.keys)
        log.info("service started", extra={"data_dir": str(settings.data_dir),
                                           "queue": settings.queue.value})  # fmt: skip
        sweeper = asyncio.create_task(sweep_forever(state))
        yield
        sweeper.cancel()
        with contextlib.suppress(asyncio.CancelledError):
            await sweeper
        await state.close()
        log.info("service stopped")

    app = FastAPI(
        title="sparsesplat",
        version=__version__,
        summary="Sparse-view Gaussian splatting: train from a few posed photos, render any view.",
        lifespan=lifespan,
        generate_unique_id_function=_operation_id,
    )
    app.state.settings = settings
    app.add_middleware(BodySizeLimit, max_bytes=settings.max_upload_mb * 2**20)

    @app.exception_handler(ServiceError)
    async def _service_error(request: Request, exc: ServiceError) -> JSONResponse:
        return _error(
            exc.status_code, exc.code, str(exc.detail), dict(exc.headers) if exc.headers else None
        )

    @app.exception_handler(StarletteHTTPException)
    async def _http_error(request: Request, exc: StarletteHTTPException) -> JSONResponse:
        code = _STATUS_CODES.get(exc.status_code, f"http_{exc.status_code}")
        headers = getattr(exc, "headers", None)
        return _error(exc.status_code, code, str(exc.detail), dict(headers) if headers else None)

    @app.exception_handler(RequestValidationError)
    async def _validation_error(request: Request, exc: RequestValidationError) -> JSONResponse:
        problems = "; ".join(
            f"{'.'.join(str(p) for p in err.get('loc', ()))}: "
            f"{str(err.get('msg', '')).removeprefix('Value error, ')}"
            for err in exc.errors()
        )
        return _error(422, "invalid_request", problems or "invalid request")

    @app.exception_handler(sqlalchemy.exc.OperationalError)
    async def _database_down(request: Request, exc: Exception) -> JSONResponse:
        if is_disk_full(exc):  # nothing was stored: the transaction rolled back
            log.error("the job database's disk is full", extra={"path": request.url.path})
            message = disk_full_message(
                "committing to the job database", None, free_bytes(settings.data_dir)
            )
            return _error(507, "insufficient_storage", message, {"Retry-After": "60"})
        log.warning("database unavailable", exc_info=True)
        message = "the job database is not answering; try again shortly"
        return _error(503, "database_unavailable", message, {"Retry-After": "5"})

    @app.exception_handler(ArtifactMissing)
    async def _artifact_missing(request: Request, exc: ArtifactMissing) -> JSONResponse:
        # A record whose file the artifact store lacks (deleted by hand, lost by the store).
        log.error("artifact missing", extra={"path": request.url.path, "error": str(exc)})
        return _error(404, "artifact_missing", f"a file of this job is missing: {exc}")

    @app.exception_handler(ArtifactStoreError)
    async def _artifact_store_down(request: Request, exc: ArtifactStoreError) -> JSONResponse:
        log.error("artifact store failed", extra={"path": request.url.path, "error": str(exc)})
        return _error(503, "artifact_store_unavailable", str(exc), {"Retry-After": "30"})

    @app.exception_handler(Exception)
    async def _unexpected(request: Request, exc: Exception) -> JSONResponse:
        log.exception("unhandled error", extra={"path": request.url.path})
        return _error(500, "internal_error", f"the server failed: {type(exc).__name__}")

    routers = (service.router, jobs.router, events.router, models.router, live.router, usage.router)
    for router in routers:
        app.include_router(router)
    app.include_router(pages.router)
    return app
