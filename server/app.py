"""FastAPI application factory. Routes stay thin; state lives on ``app.state``, never in modules."""

from __future__ import annotations

import logging
from collections.abc import AsyncIterator
from contextlib import asynccontextmanager

from fastapi import FastAPI, Request
from fastapi.exceptions import RequestValidationError
from fastapi.responses import JSONResponse
from starlette.exceptions import HTTPException as StarletteHTTPException

from sparsesplat import __version__
from sparsesplat.api.schemas import ErrorBody, Health
from sparsesplat.api.settings import Settings, load_settings

log = logging.getLogger("sparsesplat.server")


def create_app(settings: Settings | None = None) -> FastAPI:
    """Build the application for ``settings`` (default: read from the environment)."""
    settings = settings or load_settings()

    @asynccontextmanager
    async def lifespan(app: FastAPI) -> AsyncIterator[None]:
        settings.data_dir.mkdir(parents=True, exist_ok=True)
        log.info(
            "service starting",
            extra={"data_dir": str(settings.data_dir), "queue": settings.queue.value},
        )
        yield
        log.info("service stopped")

    app = FastAPI(title="sparsesplat", version=__version__, lifespan=lifespan)
    app.state.settings = settings

    @app.exception_handler(StarletteHTTPException)
    async def _http_error(request: Request, exc: StarletteHTTPException) -> JSONResponse:
        code = "not_found" if exc.status_code == 404 else f"http_{exc.status_code}"
        body = ErrorBody(code=code, message=str(exc.detail))
        return JSONResponse(body.model_dump(), status_code=exc.status_code)

    @app.exception_handler(RequestValidationError)
    async def _validation_error(request: Request, exc: RequestValidationError) -> JSONResponse:
        problems = "; ".join(
            f"{'.'.join(str(p) for p in err.get('loc', ()))}: {err.get('msg', '')}"
            for err in exc.errors()
        )
        body = ErrorBody(code="invalid_request", message=problems or "invalid request")
        return JSONResponse(body.model_dump(), status_code=422)

    @app.get("/healthz", response_model=Health, tags=["service"])
    async def healthz() -> Health:
        """Liveness: answers as soon as the process serves HTTP."""
        return Health(version=__version__, queue=settings.queue.value, device=settings.device.value)

    return app
