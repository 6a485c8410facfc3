"""Each exception class raised by a real server condition, retries only where safe, named
timeouts, and the extras a call needs."""

from __future__ import annotations

import asyncio
import json
import socket
import subprocess
import sys
from collections.abc import AsyncIterator, Callable, Coroutine
from contextlib import asynccontextmanager
from pathlib import Path
from typing import Any

import httpx
import numpy as np
import pytest

from sparsesplat.api.settings import Settings
from sparsesplat.client import (
    AsyncClient,
    AuthenticationError,
    Client,
    Conflict,
    ConnectionFailed,
    InvalidInput,
    NotFound,
    RateLimited,
    RetryPolicy,
    ServerError,
    ServiceUnavailable,
    Timeout,
    Timeouts,
    ValidationFailed,
    cameras,
    from_images,
)
from sparsesplat.client.errors import EXIT_CODES, exit_code
from tests.client.conftest import start_server

REPO = Path(__file__).resolve().parents[2]
KEY = "test-key-1234"
NO_RETRY = RetryPolicy(max_retries=0)


def _camera(**change: Any) -> dict[str, Any]:
    k = cameras.Intrinsics.from_fov(32, 32, 50)
    cam = cameras.look_at((0, -4, 1), (0, 0, 0), intrinsics=k).model_dump(mode="json")
    cam.update(change)
    return cam


def _tiny_upload() -> Any:
    """3 random 32x32 images on a ring of cameras (a job that can be queued, not trained)."""
    k = cameras.Intrinsics.from_fov(32, 32, 50)
    cams = cameras.orbit((0, 0, 0), 4.0, 3, intrinsics=k, arc_deg=60)
    rng = np.random.default_rng(0)
    images = [rng.integers(0, 255, (32, 32, 3), dtype=np.uint8) for _ in cams]
    return from_images(images, cams)


@asynccontextmanager
async def _app(tmp_path: Path, **settings: Any) -> AsyncIterator[httpx.ASGITransport]:
    """The FastAPI app in-process (lifespan run), no workers: fast and deterministic."""
    from sparsesplat.server.app import create_app

    app = create_app(Settings(data_dir=tmp_path / "data", **settings))
    async with app.router.lifespan_context(app):
        yield httpx.ASGITransport(app=app)


def _run(tmp_path: Path, body: Callable[[httpx.ASGITransport], Coroutine[Any, Any, None]],
         **settings: Any) -> None:  # fmt: skip
    async def main() -> None:
        async with _app(tmp_path, **settings) as transport:
            await body(transport)

    asyncio.run(main())


def test_each_error_kind_from_the_server(tmp_path: Path) -> None:
    async def body(transport: httpx.ASGITransport) -> None:
        base = "http://sparsesplat.test"
        async with AsyncClient(base, "wrong-key", retry=NO_RETRY, transport=transport) as bad:
            with pytest.raises(AuthenticationError) as auth:
                await bad.jobs()
            assert auth.value.status == 401 and "API key" in auth.value.message
        async with AsyncClient(base, KEY, retry=NO_RETRY, transport=transport) as client:
            with pytest.raises(NotFound) as missing:
                await client.get_job("job_does_not_exist")
            assert missing.value.code == "job_not_found"
            with pytest.raises(NotFound):
                await client.delete("job_does_not_exist")
            # A non-rigid pose: the server's message says what is wrong.
            sheared = _camera(matrix=[[1, 0.5, 0, 0], [0, 1, 0, 0], [0, 0, 1, 4], [0, 0, 0, 1]])
            with pytest.raises(ValidationFailed) as invalid:
                await client.model("job_x").render_bytes(sheared)
            assert invalid.value.status == 422 and "not rigid" in invalid.value.message
            # A job that has not trained yet has no model: 409.
            job = await client.submit(_tiny_upload(), {"iterations": 5})
            with pytest.raises(Conflict) as early:
                await job.model.render_bytes(_camera())
            assert early.value.code == "model_not_ready"
            # 0.5 renders/s with bursts of 1: the next one is refused with Retry-After.
            with pytest.raises(RateLimited) as limited:
                await job.model.render_bytes(_camera())
            assert limited.value.retry_after is not None and limited.value.retry_after >= 1
            # The submission was idempotent: the same key returns the same job.
            again = await client.submit(_tiny_upload(), {"iterations": 5}, idempotency_key="k1")
            same = await client.submit(_tiny_upload(), {"iterations": 5}, idempotency_key="k1")
            assert again.id == same.id != job.id
            cancelled = await same.cancel()
            assert cancelled.state.value == "cancelled"
            await same.delete()
            with pytest.raises(NotFound):
                await same.refresh()

    _run(tmp_path, body, api_keys=[KEY], renders_per_second=0.5)


def test_upload_refused_with_the_servers_message(tmp_path: Path) -> None:
    async def body(transport: httpx.ASGITransport) -> None:
        async with AsyncClient("http://t", transport=transport, retry=NO_RETRY) as client:
            upload = _tiny_upload()
            upload.cameras["frames"][0]["width"] = 64  # the image is 32 wide
            with pytest.raises(ValidationFailed) as refused:
                await client.submit(upload)
            assert refused.value.code == "size_mismatch"
            assert "32x32" in refused.value.message

    _run(tmp_path, body)


def test_event_stream_errors_and_server_stopped(tmp_path: Path) -> None:
    """A real server with a key and no workers: the WebSocket refusals map to the same
    classes as HTTP; once the server is stopped every call is a ConnectionFailed."""
    no_workers = {"SPARSESPLAT_WORKERS": "0", "SPARSESPLAT_RENDER_WORKERS": "0"}
    server = start_server(tmp_path, False, SPARSESPLAT_API_KEYS=f'["{KEY}"]', **no_workers)
    try:
        fast = RetryPolicy(max_retries=1, backoff_s=0.05, reconnect_s=0.2)
        with Client(server.url, KEY, retry=fast) as client:
            assert client.health().status == "ok"
            ready = client.ready()  # 503 with its body: no workers
            assert not ready.ready and ready.problems
            job = client.submit(_tiny_upload(), {"iterations": 5})
            with (
                Client(server.url, "wrong-key", retry=fast) as stranger,
                pytest.raises(AuthenticationError),
            ):
                list(stranger.events(job.id))
            with pytest.raises(NotFound):
                list(client.events("job_does_not_exist"))
            with pytest.raises(Timeout):  # queued forever: no worker
                list(job.events(timeout=1.0))
            server.stop()
            with pytest.raises(ConnectionFailed) as lost:
                client.get_job(job.id)
            assert server.url.split("//")[1] in str(lost.value)
            assert isinstance(lost.value, ConnectionError)
            with pytest.raises(ConnectionFailed):
                list(client.events(job.id))
    finally:
        server.stop()


def test_a_silent_server_times_out() -> None:
    listener = socket.socket()
    listener.bind(("127.0.0.1", 0))
    listener.listen(4)  # accepts connections, never answers
    port = listener.getsockname()[1]
    try:
        timeouts = Timeouts(read=0.3, connect=1.0)
        with Client(f"http://127.0.0.1:{port}", timeouts=timeouts, retry=NO_RETRY) as client:
            with pytest.raises(Timeout) as slow:
                client.get_job("job_x")
            assert isinstance(slow.value, TimeoutError)
    finally:
        listener.close()


# ---------------------------------------------------------------- retries (mock transport)


def _counting(answers: list[httpx.Response]) -> tuple[httpx.MockTransport, list[httpx.Request]]:
    seen: list[httpx.Request] = []

    def handler(request: httpx.Request) -> httpx.Response:
        seen.append(request)
        return answers[min(len(seen) - 1, len(answers) - 1)]

    return httpx.MockTransport(handler), seen


JOB = {
    "id": "job_1", "state": "queued", "spec": {}, "created_at": "2026-01-01T00:00:00Z",
    "n_train_views": 3, "n_test_views": 0,
}  # fmt: skip
FAST = RetryPolicy(max_retries=3, backoff_s=0.001)


def test_idempotent_calls_retry_with_backoff() -> None:
    busy = httpx.Response(503, json={"code": "database_unavailable", "message": "try again"})
    transport, seen = _counting([busy, busy, httpx.Response(200, json=JOB)])
    with Client("http://t", transport=transport, retry=FAST) as client:
        assert client.get_job("job_1").id == "job_1"
    assert len(seen) == 3


def test_submissions_retry_only_with_an_idempotency_key() -> None:
    busy = httpx.Response(503, json={"code": "x", "message": "busy"})
    transport, seen = _counting([busy, httpx.Response(201, json=JOB)])
    with Client("http://t", transport=transport, retry=FAST) as client:
        client.submit(_tiny_upload())  # a key is sent automatically
    keys = {r.headers.get("idempotency-key") for r in seen}
    assert len(seen) == 2 and len(keys) == 1 and None not in keys
    transport, seen = _counting([busy, httpx.Response(201, json=JOB)])
    with (
        Client("http://t", transport=transport, retry=FAST) as client,
        pytest.raises(ServiceUnavailable),
    ):
        client.submit(_tiny_upload(), idempotency_key=None)
    assert len(seen) == 1 and "idempotency-key" not in seen[0].headers


def test_errors_are_not_retried_and_map_to_classes() -> None:
    for status, kind in ((400, ValidationFailed), (500, ServerError), (404, NotFound)):
        transport, seen = _counting([httpx.Response(status, json={"code": "c", "message": "m"})])
        with Client("http://t", transport=transport, retry=FAST) as client, pytest.raises(kind):
            client.get_job("job_1")
        assert len(seen) == 1
    # A long Retry-After is not slept through: the caller decides.
    limited = httpx.Response(429, headers={"Retry-After": "60"}, json={"code": "c", "message": "m"})
    transport, seen = _counting([limited])
    with (
        Client("http://t", transport=transport, retry=FAST) as client,
        pytest.raises(RateLimited) as exc,
    ):
        client.get_job("job_1")
    assert exc.value.retry_after == 60 and len(seen) == 1


def test_exit_codes_are_distinct() -> None:
    assert len(set(EXIT_CODES.values())) == len(EXIT_CODES) - 1  # InvalidInput shares 2
    assert exit_code(ServiceUnavailable(503, "c", "m")) == EXIT_CODES[ServerError]
    assert exit_code(InvalidInput("x")) == 2


# ---------------------------------------------------------------- extras


_BLOCKED = """
import sys
class Block:
    def find_spec(self, name, path=None, target=None):
        if name.split(".")[0] in ("torch", "numpy", "PIL", "imageio", "pandas", "fastapi"):
            raise ModuleNotFoundError(f"No module named {name!r}", name=name)
        return None
sys.meta_path.insert(0, Block())
"""


@pytest.mark.shared_data
def test_sdk_without_numpy_or_pillow(tmp_path: Path) -> None:
    """The base install submits files and folders of the JSON formats; array/image calls say
    which extra to install."""
    probe = (
        _BLOCKED
        + f"""
import json
from sparsesplat.client import Client, MissingExtra, read_scene, media
from sparsesplat.client import cameras as cams
from sparsesplat.client.scenes import from_images
mic = {str(REPO.parent / "shared" / "data" / "nerf_synthetic" / "mic")!r}
out = {{}}
try:
    up = read_scene(mic, views=3, test_views=1)
    out["folder"] = [up.n_train, up.n_test, up.preset]
except Exception as exc:
    out["folder"] = repr(exc)
for name, call in (
    ("array", lambda: media.decode_array(b"x")),
    ("downscale", lambda: read_scene(mic, views=3, downscale=2)),
    ("from_arrays", lambda: from_images([object()], [cams.look_at(
        (0, -4, 0), (0, 0, 0), intrinsics=cams.Intrinsics(10, 10, 5, 5, 10, 10))])),
    ("frame", lambda: media.require("pandas", "metrics as a DataFrame")),
):
    try:
        call()
        out[name] = "no error"
    except MissingExtra as exc:
        out[name] = str(exc)
    except Exception as exc:
        out[name] = repr(exc)
out["loaded"] = sorted(m for m in ("torch", "numpy", "PIL") if m in sys.modules)
print(json.dumps(out))
"""
    )
    done = subprocess.run([sys.executable, "-c", probe], capture_output=True, text=True,
                          timeout=120, cwd=REPO)  # fmt: skip
    assert done.returncode == 0, done.stderr
    out = json.loads(done.stdout)
    if (REPO.parent / "shared" / "data").is_dir():
        assert out["folder"] == [3, 1, "blender"]
    assert "pip install 'sparsesplat[images]'" in out["array"]
    assert "pip install 'sparsesplat[images]'" in out["downscale"]
    assert "pip install 'sparsesplat[images]'" in out["from_arrays"]
    assert "pip install 'sparsesplat[pandas]'" in out["frame"]
    assert out["loaded"] == []


def test_cli_render_of_a_local_checkpoint_without_torch_names_the_engine_extra(
    tmp_path: Path,
) -> None:
    checkpoint = tmp_path / "checkpoint.pt"
    checkpoint.write_bytes(b"not really")
    probe = _BLOCKED + "from sparsesplat.client.cli import main\nsys.exit(main(sys.argv[1:]))"
    done = subprocess.run(
        [sys.executable, "-c", probe, "render", str(checkpoint), "--camera",
         json.dumps(_camera()), "-o", str(tmp_path / "o.png")],
        capture_output=True, text=True, timeout=120, cwd=REPO,
    )  # fmt: skip
    assert done.returncode == 3, done.stderr
    assert "pip install 'sparsesplat[engine]'" in done.stderr


def test_submit_offers_every_preset_the_spec_accepts() -> None:
    import subprocess
    import sys
    from typing import get_args

    from sparsesplat.api.jobs import PresetName

    help_text = subprocess.run(
        [sys.executable, "-m", "sparsesplat", "submit", "--help"],
        capture_output=True, text=True, check=True,
    ).stdout  # fmt: skip
    assert "{" + ",".join(get_args(PresetName)) + "}" in help_text
