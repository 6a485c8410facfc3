"""``/v1/models/{id}``: a succeeded job's model — information, renders at any pose, exports."""

from __future__ import annotations

import asyncio
import json
import time
from typing import Annotated, Literal, get_args

from fastapi import APIRouter, Query, Response
from fastapi.responses import FileResponse
from pydantic import ValidationError

from sparsesplat.api.artifacts import ArtifactMissing
from sparsesplat.api.cameras import AxisConvention, PinholeCamera, PoseDirection
from sparsesplat.api.jobs import ModelInfo
from sparsesplat.api.names import ARTIFACT_FILES, ExportFormat
from sparsesplat.api.renders import DEFAULT_RENDER_MODE, RenderMode, RenderOutput, RenderRequest
from sparsesplat.server.deps import OwnerDep, ServiceDep, check_render_size, own_model
from sparsesplat.server.errors import ServiceError, invalid, not_found, pydantic_message
from sparsesplat.server.render_dispatch import NoRenderWorker, RenderFailed
from sparsesplat.server.state import ServiceState

router = APIRouter(prefix="/v1/models", tags=["models"])

EXPORTS = {
    fmt: (fmt, "application/octet-stream", ARTIFACT_FILES[fmt]) for fmt in get_args(ExportFormat)
}
"""Export format → (artifact kind, media type, download name)."""


@router.get("/{model_id}", response_model=ModelInfo, summary="Describe a trained model")
def get_model(model_id: str, service: ServiceDep, owner: OwnerDep) -> ModelInfo:
    """Size, final held-out metrics, exports and the cameras it was trained with (the upload's,
    or as refined in training when the training poses were refined)."""
    job = own_model(service, owner, model_id)
    result = service.jobs.result(model_id) or {}
    storage = service.storage
    document = result.get("cameras") or json.loads(
        storage.fetch(storage.upload_dir(model_id) / "cameras.json").read_text()
    )
    cameras = [
        {**frame, "convention": document["convention"], "pose": document["pose"]}
        for frame in document["frames"]
    ]
    exports = [name for name, (kind, _, _) in EXPORTS.items()
               if storage.has(storage.artifact(model_id, kind))]  # fmt: skip
    return ModelInfo(
        id=model_id,
        n_gaussians=int(result.get("n_gaussians", 0)),
        iterations=int(result.get("iterations", 0)),
        metrics={k: result.get("metrics", {}).get(k) for k in MODEL_METRICS}
        | {k: v for k, v in result.get("metrics", {}).items() if k in BUDGET_METRICS},
        exports=exports,
        cameras=cameras,
        background=tuple(result["background"]) if result.get("background") else None,
        disk_bytes=result.get("disk_bytes"),
        depth_priors=sum(
            storage.has(storage.prior_picture(model_id, k))
            for k in range(sum(c.get("split", "train") == "train" for c in cameras))
        ),
        pinned=job.pinned,
        expires_at=job.expires_at,
    )


@router.put("/{model_id}/pin", response_model=ModelInfo, summary="Keep a model past expiry")
def pin_model(model_id: str, service: ServiceDep, owner: OwnerDep) -> ModelInfo:
    """Pin the model: the service's model expiry (``SPARSESPLAT_MODEL_TTL_DAYS``) passes it
    by. An expired model cannot be pinned (its files are gone)."""
    own_model(service, owner, model_id)
    if not service.jobs.set_pinned(model_id, True):
        raise not_found("model", model_id)
    return get_model(model_id, service, owner)


@router.delete("/{model_id}/pin", response_model=ModelInfo, summary="Let a model expire")
def unpin_model(model_id: str, service: ServiceDep, owner: OwnerDep) -> ModelInfo:
    """Unpin the model: it expires with the others (at once if it is past its time)."""
    own_model(service, owner, model_id)
    if not service.jobs.set_pinned(model_id, False):
        raise not_found("model", model_id)
    return get_model(model_id, service, owner)


MODEL_METRICS = ("psnr", "ssim", "lpips", "avge")
"""The held-out metrics every model reports (None where unavailable)."""
BUDGET_METRICS = ("seconds", "time_budget_s", "time_limit_s")
"""Training seconds used and, for a job with a time budget, the budget, or for a job of the
preset's default length, its time limit (when stored)."""


async def _render(
    service: ServiceState, owner: str, model_id: str, request: RenderRequest
) -> Response:
    wait = service.render_limit.acquire(owner)
    if wait > 0:
        raise ServiceError(
            429, "rate_limited",
            f"more than {service.settings.renders_per_second:g} renders per second for this key",
            {"Retry-After": str(max(1, round(wait + 0.5)))},
        )  # fmt: skip
    check_render_size(service, request)
    await asyncio.to_thread(own_model, service, owner, model_id)
    started = time.perf_counter()
    try:
        answer = await service.renders.render(model_id, request)
    except NoRenderWorker as exc:
        raise ServiceError(503, "no_render_worker", str(exc), {"Retry-After": "5"}) from exc
    except RenderFailed as exc:
        if exc.status == 404:
            raise not_found("model", model_id) from exc
        raise ServiceError(500, "render_failed", str(exc)) from exc
    service.metrics.render_seconds.observe(time.perf_counter() - started)
    headers = {k: v for k, v in answer.headers.items() if k.lower().startswith("x-")}
    return Response(answer.content, media_type=answer.headers["content-type"], headers=headers)


@router.post(
    "/{model_id}/render",
    summary="Render the model at a camera (or a camera path)",
    responses={200: {"content": {"image/png": {}, "application/zip": {}}}},
)
async def render_model(
    model_id: str, request: RenderRequest, service: ServiceDep, owner: OwnerDep
) -> Response:
    """One camera → an image (or depth/alpha); a ``path`` → a ZIP of numbered frames."""
    return await _render(service, owner, model_id, request)


@router.get(
    "/{model_id}/render",
    summary="Render at a camera given in the query (for <img> tags)",
    responses={200: {"content": {"image/png": {}}}},
)
async def render_model_get(
    model_id: str,
    service: ServiceDep,
    owner: OwnerDep,
    convention: AxisConvention,
    pose: PoseDirection,
    matrix: Annotated[str, Query(description="16 comma-separated numbers, row-major")],
    fx: float,
    fy: float,
    cx: float,
    cy: float,
    width: int,
    height: int,
    output: RenderOutput = "png",
    downscale: Annotated[int, Query(ge=1, le=16)] = 1,
    quality: Annotated[int, Query(ge=1, le=100)] = 90,
    mode: RenderMode = DEFAULT_RENDER_MODE,
) -> Response:
    """The same render as the POST form, with the camera in query parameters."""
    try:
        values = [float(v) for v in matrix.split(",")]
    except ValueError as exc:
        raise invalid("invalid_camera", "matrix: 16 comma-separated numbers expected") from exc
    if len(values) != 16:
        raise invalid("invalid_camera", f"matrix: 16 numbers expected, got {len(values)}")
    try:
        camera = PinholeCamera(
            convention=convention, pose=pose,
            matrix=[values[i : i + 4] for i in range(0, 16, 4)],
            fx=fx, fy=fy, cx=cx, cy=cy, width=width, height=height,
        )  # fmt: skip
        request = RenderRequest(
            camera=camera, output=output, downscale=downscale, quality=quality, mode=mode
        )
    except ValidationError as exc:
        raise invalid("invalid_camera", pydantic_message(exc, "camera")) from exc
    return await _render(service, owner, model_id, request)


@router.get("/{model_id}/export/{format}", summary="Download the model")
def export_model(
    model_id: str,
    format: Literal["ply", "splat", "checkpoint"],
    service: ServiceDep,
    owner: OwnerDep,
) -> FileResponse:
    """``ply`` (INRIA 3DGS layout with baked SH colour; opens in standard viewers), ``splat``
    (antimatter15 layout) or ``checkpoint`` (sparsesplat's own, for resuming or rendering)."""
    own_model(service, owner, model_id)
    kind, media, name = EXPORTS[format]
    try:
        path = service.storage.fetch(service.storage.artifact(model_id, kind))
    except ArtifactMissing:
        raise ServiceError(
            404, "export_missing", f"model {model_id} has no {format} export"
        ) from None
    return FileResponse(path, media_type=media, filename=f"{model_id}-{name}")
