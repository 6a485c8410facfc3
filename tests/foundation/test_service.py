"""The real service on loopback: started as `sparsesplat serve` in its own process."""

from __future__ import annotations

import asyncio
import os
import signal
import socket
import subprocess
import sys
import time
from collections.abc import Iterator
from pathlib import Path

import httpx
import pytest

from sparsesplat import __version__
from sparsesplat.api.schemas import Health
from sparsesplat.client import AsyncClient, Client, ConnectionFailed, NotFound

REPO = Path(__file__).resolve().parents[2]


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


@pytest.fixture(scope="module")
def service(tmp_path_factory: pytest.TempPathFactory) -> Iterator[str]:
    port = _free_port()
    data_dir = tmp_path_factory.mktemp("data")
    env = {**os.environ, "SPARSESPLAT_DATA_DIR": str(data_dir), "SPARSESPLAT_PORT": str(port)}
    proc = subprocess.Popen(
        [sys.executable, "-m", "sparsesplat", "serve"],
        cwd=REPO,
        env=env,
        stdout=subprocess.PIPE,
        stderr=subprocess.STDOUT,
        text=True,
    )
    url = f"http://127.0.0.1:{port}"
    deadline = time.monotonic() + 60
    while time.monotonic() < deadline:
        if proc.poll() is not None:
            pytest.fail(f"server exited early: {proc.stdout.read() if proc.stdout else ''}")
        try:
            if httpx.get(f"{url}/healthz", timeout=1).status_code == 200:
                break
        except httpx.TransportError:
            time.sleep(0.2)
    else:
        proc.kill()
        pytest.fail("server did not answer /healthz within 60 s")
    yield url
    proc.send_signal(signal.SIGINT)
    try:
        out, _ = proc.communicate(timeout=20)
    except subprocess.TimeoutExpired:
        proc.kill()
        out, _ = proc.communicate()
    assert data_dir.is_dir()
    # every log line the server wrote is one JSON object
    import json

    for line in filter(None, out.splitlines()):
        json.loads(line)


def test_healthz_answers_200(service: str) -> None:
    response = httpx.get(f"{service}/healthz")
    assert response.status_code == 200
    body = response.json()
    kernels = {"kernels": body.pop("kernels"), "detail": body.pop("kernels_detail")}
    free = body.pop("disk_free_bytes")
    assert body == {
        "status": "ok",
        "version": __version__,
        "queue": "local",
        "device": "cpu",
        "disk": "ok",
    }
    assert isinstance(free, int) and free > 0
    # The workers build (here: load, cached) the native kernels as they start; before the first
    # worker has got that far there is no status yet.
    assert kernels["kernels"] in (None, "building", "ready"), kernels


def test_healthz_says_when_the_kernels_are_ready(service: str) -> None:
    """The workers' start-up build ends in "ready" with each kernel's instruction set."""
    deadline = time.monotonic() + 600
    while (body := httpx.get(f"{service}/healthz").json())["kernels"] in (None, "building"):
        assert time.monotonic() < deadline, body
        time.sleep(0.5)
    assert body["kernels"] == "ready", body
    assert body["kernels_detail"].startswith("native CPU kernels ready: "), body
    assert "rasterizer avx" in body["kernels_detail"], body


def test_sdk_twins_agree(service: str) -> None:
    with Client(service) as client:
        sync_health = client.health()

    async def fetch() -> Health:
        async with AsyncClient(service) as aclient:
            return await aclient.health()

    async_health = asyncio.run(fetch())
    # The free bytes move with whatever else writes to the disk between the two calls, and a
    # kernel build's detail line counts its seconds: the twins must agree on the rest.
    volatile = {"disk_free_bytes", "kernels_detail"}
    assert async_health.model_dump(exclude=volatile) == sync_health.model_dump(exclude=volatile)
    assert async_health.disk_free_bytes is not None and async_health.disk_free_bytes > 0


def test_unknown_route_is_a_typed_error(service: str) -> None:
    response = httpx.get(f"{service}/no-such-thing")
    assert response.status_code == 404
    assert response.json()["code"] == "not_found"
    with Client(service) as client, pytest.raises(NotFound):
        client.get_job("job_00000000000000000000")


def test_cli_health_command(service: str) -> None:
    result = subprocess.run(
        [sys.executable, "-m", "sparsesplat", "health", "--url", service],
        cwd=REPO,
        capture_output=True,
        text=True,
        timeout=60,
    )
    assert result.returncode == 0, result.stderr
    assert '"status":"ok"' in result.stdout


def test_unreachable_service_is_a_clear_error() -> None:
    url = f"http://127.0.0.1:{_free_port()}"
    with Client(url, timeouts=2) as client, pytest.raises(ConnectionFailed, match="cannot reach"):
        client.health()
