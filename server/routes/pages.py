"""The web page: ``/`` and its static files under ``/static/``.

No build step and nothing from a CDN: ``server/static/index.html`` loads ES modules from
``server/static/js`` and the vendored libraries in ``server/static/vendor`` (three.js, Spark,
uPlot at pinned npm versions, refreshed by ``scripts/refresh-web-assets``) through an
importmap. The page itself is public; everything it shows comes from the ``/v1`` API with the
caller's key.
"""

from __future__ import annotations

from pathlib import Path

from fastapi import APIRouter
from fastapi.responses import FileResponse

from sparsesplat.server.errors import ServiceError

router = APIRouter(include_in_schema=False)

STATIC_DIR = Path(__file__).resolve().parent.parent / "static"
"""The page's files (index.html, app modules, vendored libraries)."""

MEDIA_TYPES = {
    ".html": "text/html; charset=utf-8",
    ".js": "text/javascript; charset=utf-8",
    ".mjs": "text/javascript; charset=utf-8",
    ".css": "text/css; charset=utf-8",
    ".json": "application/json",
    ".md": "text/markdown; charset=utf-8",
    ".svg": "image/svg+xml",
    ".png": "image/png",
    ".ico": "image/x-icon",
    "": "text/plain; charset=utf-8",
}
"""Content types by suffix: explicit, because browsers refuse a module served as anything but
JavaScript and the system's MIME table varies between machines."""

VENDOR_CACHE = "public, max-age=86400"
"""Vendored libraries change only with a pinned version bump."""
APP_CACHE = "no-cache"
"""The page's own files: revalidated on every load, so an upgraded server is picked up."""


def _static_file(relative: str) -> Path:
    """The file ``relative`` under STATIC_DIR, or a 404 (nothing outside it, no folders)."""
    root = STATIC_DIR.resolve()
    target = (root / relative).resolve()
    if not target.is_relative_to(root) or not target.is_file():
        raise ServiceError(404, "not_found", f"no static file {relative!r}")
    return target


@router.api_route("/", methods=["GET", "HEAD"])
def index() -> FileResponse:
    """The single-page app: jobs, a job's progress and error curve, the viewer."""
    return FileResponse(
        _static_file("index.html"), media_type=MEDIA_TYPES[".html"],
        headers={"Cache-Control": APP_CACHE},
    )  # fmt: skip


@router.api_route("/static/{path:path}", methods=["GET", "HEAD"])
def static(path: str) -> FileResponse:
    """One of the page's files."""
    target = _static_file(path)
    media = MEDIA_TYPES.get(target.suffix, "application/octet-stream")
    cache = VENDOR_CACHE if path.startswith("vendor/") else APP_CACHE
    return FileResponse(target, media_type=media, headers={"Cache-Control": cache})
