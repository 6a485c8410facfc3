"""A render worker process: renders stored models at requested cameras, over loopback HTTP.

The API process never renders (it must stay responsive, and it has no torch); it forwards each
validated request here. Loaded models stay in an LRU cache with their view-independent part
(the neural colour field's per-Gaussian features) precomputed, so a repeated render of one
model costs a rasterization plus the small view-dependent colour step. One render at a time
per process (connections are threaded): a render uses every torch thread it is given. Models,
their renders and the encoded outputs come from the trained-model package (``engine/model/``);
this process never loads the training package (tests/engine/model/test_model_package.py).

Protocol: ``POST /render`` with JSON ``{"model_id": ..., "request": RenderRequest}`` answers
the encoded bytes (a ZIP of frames for a camera path); ``GET /healthz`` answers ``ok``.
"""

from __future__ import annotations

import contextlib
import io
import json
import logging
import os
import threading
import time
import zipfile
from collections import OrderedDict
from http.server import BaseHTTPRequestHandler, ThreadingHTTPServer
from typing import TYPE_CHECKING, Any

from sparsesplat.api.renders import (
    EMPTY_RENDER_COVERAGE,
    MEDIA_TYPES,
    RENDER_WARNING_HEADER,
    RenderRequest,
    empty_renders,
)
from sparsesplat.api.settings import Settings
from sparsesplat.api.storage import Storage, StorageError
from sparsesplat.api.store.database import make_engine
from sparsesplat.api.store.workers import WorkerRegistry, new_worker_id
from sparsesplat.worker.kernels import prepare_kernels

if TYPE_CHECKING:
    from sparsesplat.engine.model import TrainedModel

log = logging.getLogger("sparsesplat.render")


class ModelCache:
    """The most recently used trained models, ready to render."""

    def __init__(self, storage: Storage, capacity: int, device: str) -> None:
        """Keep at most ``capacity`` models of ``storage`` loaded on ``device``."""
        self.storage = storage
        self.capacity = capacity
        self.device = device
        self._models: OrderedDict[str, tuple[float, TrainedModel]] = OrderedDict()
        self._export_read: set[str] = set()  # loaded models given their export's SH (if any)

    def get(self, model_id: str, mode: str = "neural") -> TrainedModel:
        """The loaded model (reloaded when its checkpoint changed), ready to render in ``mode``;
        FileNotFoundError if none."""
        from sparsesplat.engine.model import load_model

        # A succeeded job's model never changes: a copy here (from the artifact store, when
        # one is set) serves until evicted. FileNotFoundError when the model does not exist.
        path = self.storage.fetch(self.storage.artifact(model_id, "checkpoint"))
        mtime = path.stat().st_mtime
        cached = self._models.get(model_id)
        if cached is not None and cached[0] == mtime:
            self._models.move_to_end(model_id)
            model = cached[1]
        else:
            model = load_model(path, self.device)
            self._store(model_id, mtime, model)
        if mode == "baked" and model_id not in self._export_read:
            # Read on the first baked render only: most models are only ever rendered exactly.
            # The run's export holds the bake fitted to the training directions too.
            ply = self.storage.artifact(model_id, "ply")
            with contextlib.suppress(FileNotFoundError):  # no export: the model bakes its own
                ply = self.storage.fetch(ply)
            model.use_export_sh(ply)
            self._export_read.add(model_id)
        return model

    def _store(self, model_id: str, mtime: float, model: TrainedModel) -> None:
        self._export_read.discard(model_id)
        self._models[model_id] = (mtime, model)
        self._models.move_to_end(model_id)
        while len(self._models) > self.capacity:
            gone, _ = self._models.popitem(last=False)
            self._export_read.discard(gone)

    def __len__(self) -> int:
        return len(self._models)


class Renderer:
    """Renders requests against the model cache."""

    def __init__(self, cache: ModelCache) -> None:
        """Render models held by ``cache``."""
        self.cache = cache
        # Connections are served by threads (keep-alive from the API's pool must not block
        # other connections), but renders run one at a time: each uses every torch thread.
        self._lock = threading.Lock()

    def render(self, model_id: str, request: RenderRequest) -> tuple[bytes, str, dict[str, str]]:
        """(body, media type, extra headers) for one request."""
        from sparsesplat.engine.camera import Camera

        seconds = 0.0
        frames = []
        coverages = []
        for camera in request.cameras:
            # Only the render holds the lock: encoding (Pillow releases the GIL) overlaps the
            # next request's render when several wait.
            with self._lock:
                started = time.perf_counter()
                model = self.cache.get(model_id, request.mode)
                out = model.render(Camera.from_wire(camera, request.downscale), mode=request.mode)
                seconds += time.perf_counter() - started
            started = time.perf_counter()
            frames.append(_encode_render(out, request))
            coverages.append(float(out.alpha.mean()))
            seconds += time.perf_counter() - started
        # The worker's own share of the latency (model lookup, render, encoding; not the wait
        # for the lock), so that a client can tell it from the hops and the queueing.
        headers = {"X-Render-Ms": f"{1000 * seconds:.1f}"}
        headers["X-Coverage"] = ",".join(f"{coverage:.4f}" for coverage in coverages)
        empty = empty_renders(coverages)
        if empty:
            which = (
                "the camera sees"
                if request.path is None
                else (f"{len(empty)} of {len(frames)} cameras (from {empty[0]}) see")
            )
            headers[RENDER_WARNING_HEADER] = (
                f"{which} nothing of the model (under {EMPTY_RENDER_COVERAGE:.0%} of pixels "
                "covered): check the camera's 'convention' and 'pose', and that it is near "
                "the training cameras and faces the scene"
            )
        if request.output == "depth16":
            from sparsesplat.engine.model.encode import DEPTH16_UNITS_PER_SCENE_UNIT

            headers["X-Depth-Scale"] = str(DEPTH16_UNITS_PER_SCENE_UNIT)
        if request.path is None:
            return frames[0], MEDIA_TYPES[request.output], headers
        suffix = {"jpeg": "jpg", "depth16": "png", "alpha": "png"}.get(
            request.output, request.output
        )
        buffer = io.BytesIO()
        with zipfile.ZipFile(buffer, "w", zipfile.ZIP_STORED) as archive:
            for i, frame in enumerate(frames):
                archive.writestr(f"{i:04d}.{suffix}", frame)
        return buffer.getvalue(), MEDIA_TYPES["zip"], headers


def _encode_render(out: Any, request: RenderRequest) -> bytes:
    """The bytes of ``request.output`` for one render (a RasterOutput)."""
    from sparsesplat.engine.model.encode import encode

    # Views of the render's memory, not copies: the encoder reads them once.
    image = out.image.permute(1, 2, 0).cpu().numpy()
    depth, alpha = out.depth[0].cpu().numpy(), out.alpha[0].cpu().numpy()
    return encode(request.output, image, depth, alpha, request.quality)


def _handler(renderer: Renderer) -> type[BaseHTTPRequestHandler]:
    class Handler(BaseHTTPRequestHandler):
        protocol_version = "HTTP/1.1"
        # The headers and the body go out in separate writes: with Nagle's algorithm the body's
        # last segment can wait for the API's delayed ACK (tens of ms) on every keep-alive reply.
        disable_nagle_algorithm = True

        def log_message(self, format: str, *args: Any) -> None:  # quiet: the API logs requests
            pass

        def do_GET(self) -> None:
            self._reply(200, b"ok", "text/plain", {})

        def do_POST(self) -> None:
            try:
                length = int(self.headers.get("Content-Length", "0"))
                payload = json.loads(self.rfile.read(length))
                request = RenderRequest.model_validate(payload["request"])
                body, media, headers = renderer.render(str(payload["model_id"]), request)
            except (FileNotFoundError, StorageError):
                self._reply(404, b'{"code":"model_not_found","message":"no such model"}',
                            "application/json", {})  # fmt: skip
                return
            except Exception as exc:  # reported to the API, which answers 500 with the message
                log.exception("render failed")
                message = json.dumps({"code": "render_failed", "message": str(exc)[:500]})
                self._reply(500, message.encode(), "application/json", {})
                return
            self._reply(200, body, media, headers)

        def _reply(self, status: int, body: bytes, media: str, headers: dict[str, str]) -> None:
            self.send_response(status)
            self.send_header("Content-Type", media)
            self.send_header("Content-Length", str(len(body)))
            for key, value in headers.items():
                self.send_header(key, value)
            self.end_headers()
            self.wfile.write(body)

    return Handler


def serve_renders(settings: Settings, host: str = "127.0.0.1", port: int = 0) -> None:
    """Listen on ``host:port`` (0: any free port), register in the database, serve forever."""
    import torch

    assert settings.database_url is not None
    torch.set_num_threads(settings.render_threads)
    prepare_kernels(settings)  # before registering: no render request waits on the compiler
    device = settings.device.value if settings.device.value != "auto" else (
        "cuda" if torch.cuda.is_available() else "cpu"
    )  # fmt: skip
    cache = ModelCache(Storage.for_settings(settings), settings.render_cache_models, device)
    ThreadingHTTPServer.request_queue_size = 128  # bursts of connections must not be refused
    server = ThreadingHTTPServer((host, port), _handler(Renderer(cache)))
    address = f"{host}:{server.server_address[1]}"
    registry = WorkerRegistry(make_engine(settings.database_url))
    worker_id = new_worker_id("render")
    registry.register(worker_id, "render", address)

    parent = os.getppid()

    def beat() -> None:
        while True:
            time.sleep(settings.heartbeat_s)
            if os.getppid() != parent:  # the supervisor died: do not linger as an orphan
                log.warning("parent process gone; stopping")
                server.shutdown()
                return
            try:
                registry.beat(worker_id)
            except Exception:
                log.warning("render heartbeat failed", exc_info=True)

    threading.Thread(target=beat, daemon=True, name="render-heartbeat").start()
    log.info("render worker ready", extra={"address": address, "worker": worker_id})
    try:
        server.serve_forever()
    finally:
        registry.unregister(worker_id)
