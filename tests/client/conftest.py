"""A real ``sparsesplat serve`` on 127.0.0.1 for the SDK tests, and one smoke-scale job
trained on the shared mic scene that every test reuses."""

from __future__ import annotations

import contextlib
import os
import signal
import socket
import subprocess
import sys
import time
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

import pytest

from sparsesplat.api.jobs import Event, Job
from sparsesplat.client import Client, Upload, read_scene
from tests.service.live import answers

REPO = Path(__file__).resolve().parents[2]
MIC = REPO.parent / "shared" / "data" / "nerf_synthetic" / "mic"
SMOKE_SPEC = {"iterations": 40, "record_interval_s": 3}
"""A job that trains in about a minute on 2 busy cores."""


def free_port() -> int:
    """A TCP port nothing listens on right now."""
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


@dataclass
class Server:
    """A running service process."""

    url: str
    process: subprocess.Popen[bytes]
    data_dir: Path
    log: Path

    def stop(self) -> None:
        """Stop it, then any of its worker processes still alive (by their ids)."""
        family = _descendants(self.process.pid)
        # SIGTERM first; a following SIGINT makes uvicorn stop waiting for open connections.
        for sig in (signal.SIGTERM, signal.SIGINT):
            if self.process.poll() is None:
                self.process.send_signal(sig)
                try:
                    self.process.wait(timeout=20)
                except subprocess.TimeoutExpired:
                    continue
        if self.process.poll() is None:
            self.process.kill()
            self.process.wait()
        _end(family)


def _descendants(pid: int) -> list[int]:
    """Ids of every process below ``pid`` (Linux /proc; empty elsewhere)."""
    children: dict[int, list[int]] = {}
    for stat in Path("/proc").glob("[0-9]*/stat"):
        try:
            fields = stat.read_text().rsplit(")", 1)[1].split()
            children.setdefault(int(fields[1]), []).append(int(stat.parent.name))
        except (OSError, IndexError, ValueError):
            continue
    out, todo = [], [pid]
    while todo:
        for child in children.get(todo.pop(), []):
            out.append(child)
            todo.append(child)
    return out


def _end(pids: list[int], grace_s: float = 15.0) -> None:
    """SIGTERM the processes ``pids`` that are still alive, SIGKILL them after ``grace_s``."""

    def alive(pid: int) -> bool:
        try:
            state = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[0]
        except (OSError, IndexError):
            return False
        return state != "Z"

    for sig in (signal.SIGTERM, signal.SIGKILL):
        left = [p for p in pids if alive(p)]
        for pid in left:
            with contextlib.suppress(ProcessLookupError):
                os.kill(pid, sig)
        deadline = time.monotonic() + grace_s
        while left and time.monotonic() < deadline:
            time.sleep(0.2)
            left = [p for p in left if alive(p)]
        if not left:
            return


def start_server(tmp: Path, ready: bool = True, **env: str) -> Server:
    """``sparsesplat serve`` on a free loopback port with a fresh data dir; waits for
    ``/readyz`` (or just ``/healthz`` when ``ready`` is False)."""
    port = free_port()
    data = tmp / "data"
    log = tmp / "server.log"
    environment = {
        **os.environ,
        "SPARSESPLAT_DATA_DIR": str(data),
        "SPARSESPLAT_PORT": str(port),
        "SPARSESPLAT_HEARTBEAT_S": "1",
        "SPARSESPLAT_LEASE_S": "20",  # heartbeats every 1 s; 2 busy cores delay them
        "SPARSESPLAT_LOG_JSON": "false",
        **env,
    }
    with log.open("wb") as out:
        process = subprocess.Popen(
            [sys.executable, "-m", "sparsesplat", "serve"],
            cwd=tmp,
            env=environment,
            stdout=out,
            stderr=subprocess.STDOUT,
        )
    server = Server(f"http://127.0.0.1:{port}", process, data, log)
    path = "/readyz" if ready else "/healthz"

    def alive() -> None:
        if process.poll() is not None:
            raise RuntimeError(f"server exited: {log.read_text()[-3000:]}")

    if answers(server.url + path, 180, 0.5, alive):
        return server
    server.stop()
    raise RuntimeError(f"server not ready in time: {log.read_text()[-3000:]}")


@pytest.fixture(scope="session")
def server(tmp_path_factory: pytest.TempPathFactory) -> Iterator[Server]:
    """One service with a training and a render worker for the whole session."""
    running = start_server(tmp_path_factory.mktemp("service"))
    yield running
    running.stop()


@pytest.fixture(scope="session")
def mic_upload() -> Upload:
    """3 training + 2 held-out views of mic at 100x100, read from the Blender folder."""
    if not MIC.is_dir():
        pytest.skip(f"{MIC} not present")
    return read_scene(MIC, views=3, test_views=2, downscale=4)


@dataclass
class Trained:
    """The shared smoke job and what waiting for it saw."""

    job: Job
    events: list[Event]
    upload: Upload
    url: str


@pytest.fixture(scope="session")
def trained(server: Server, mic_upload: Upload) -> Trained:
    """Submit the mic upload, wait for it (events recorded through the callback)."""
    seen: list[Event] = []
    with Client(server.url) as client:
        handle = client.submit(mic_upload, SMOKE_SPEC)
        job = handle.wait(timeout=600, progress=False, callback=seen.append)
    return Trained(job, seen, mic_upload, server.url)
