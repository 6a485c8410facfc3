"""The service itself: liveness, readiness and Prometheus metrics."""

from __future__ import annotations

from fastapi import APIRouter, Response
from fastapi.responses import JSONResponse

from sparsesplat import __version__
from sparsesplat.api.disk import disk_state
from sparsesplat.api.kernel_status import STATUS_FILE, KernelState, read_status
from sparsesplat.api.schemas import Health, Readiness
from sparsesplat.server.deps import ServiceDep

router = APIRouter(tags=["service"])


@router.get("/healthz", response_model=Health)
async def healthz(service: ServiceDep) -> Health:
    """Liveness: answers as soon as the process serves HTTP (touches no database: a statvfs of
    the data folder, since a full disk is the first thing an operator wants to see, and the
    native kernels' build status, a small file there)."""
    settings = service.settings
    disk = disk_state(service.storage.root, settings.disk_reserve_mb * 1_000_000)
    kernels = read_status(settings.data_dir / STATUS_FILE)
    return Health(
        version=__version__,
        queue=settings.queue.value,
        device=settings.device.value,
        disk=disk.status,
        disk_free_bytes=disk.free_bytes,
        kernels=None if kernels is None else kernels.state.value,
        kernels_detail=None if kernels is None else kernels.summary(),
    )


@router.get("/readyz", response_model=Readiness, responses={503: {"model": Readiness}})
def readyz(service: ServiceDep) -> Response:
    """Ready when the database answers and a training and a render worker beat recently."""
    problems: list[str] = []
    workers: dict[str, int] = {"train": 0, "render": 0}
    try:
        for worker in service.workers.live(max_age_s=service.settings.readiness_max_age_s):
            workers[worker.kind] = workers.get(worker.kind, 0) + 1
        database = True
    except Exception as exc:
        database = False
        problems.append(f"database unreachable: {type(exc).__name__}")
    kernels = read_status(service.settings.data_dir / STATUS_FILE)
    if kernels is not None and kernels.state != KernelState.ready:
        problems.append(kernels.summary())  # workers take no work before the build ends
    for kind in ("train", "render"):
        if database and workers[kind] == 0:
            problems.append(f"no {kind} worker has sent a heartbeat recently")
    body = Readiness(ready=not problems, database=database, workers=workers, problems=problems)
    return JSONResponse(body.model_dump(), status_code=200 if body.ready else 503)


@router.get("/metrics", response_class=Response)
def metrics(service: ServiceDep) -> Response:
    """Prometheus text format: jobs by state, queue depth, workers, render latency."""
    return Response(service.metrics.exposition(), media_type="text/plain; version=0.0.4")
