"""The native kernels are built before work is taken, and the service says so meanwhile.

``sparsesplat build`` builds or loads every kernel and writes ``kernels.json``; workers run the
same build when they start; ``/healthz`` reports the file's state and ``/readyz`` is not ready
while a build runs or after one failed.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
import time
from pathlib import Path

from fastapi.testclient import TestClient

from sparsesplat.api.kernel_status import (
    STATUS_FILE,
    KernelState,
    KernelStatus,
    read_status,
    write_status,
)
from sparsesplat.api.settings import Settings
from sparsesplat.engine.kernels import KERNELS
from sparsesplat.server.app import create_app

REPO = Path(__file__).resolve().parents[2]


def _dead_pid() -> int:
    """The id of a process that has exited (and been reaped)."""
    done = subprocess.run([sys.executable, "-c", "import os; print(os.getpid())"],
                          capture_output=True, text=True, check=True)  # fmt: skip
    return int(done.stdout)


def test_status_round_trips_and_a_killed_build_reads_as_failed(tmp_path: Path) -> None:
    path = tmp_path / STATUS_FILE
    assert read_status(path) is None  # no local build
    building = KernelStatus(
        state=KernelState.building, started_at=time.time() - 42, pid=os.getpid()
    )
    write_status(path, building)
    assert read_status(path) == building
    assert (
        building.summary(building.started_at + 42)
        == "building the native CPU kernels (42 s so far)"
    )
    write_status(path, building.model_copy(update={"pid": _dead_pid()}))
    dead = read_status(path)
    assert dead is not None and dead.state == KernelState.failed
    assert "exited early" in dead.summary()
    path.write_text("{not json")
    assert read_status(path) is None


def test_build_command_builds_every_kernel_and_writes_ready(tmp_path: Path) -> None:
    status = tmp_path / "data" / STATUS_FILE
    done = subprocess.run(
        [sys.executable, "-m", "sparsesplat", "build", "--status-file", str(status), "--json"],
        cwd=REPO, capture_output=True, text=True, timeout=900,
    )  # fmt: skip
    assert done.returncode == 0, done.stderr[-3000:]
    printed = json.loads(done.stdout.strip().splitlines()[-1])
    assert set(printed["variants"]) == {k.name for k in KERNELS}
    # Native kernels, never the torch fallback: the build must work where the tests run.
    native = {"avx2", "avx512", "avx2-f32", "avx512-f32", "portable", "portable-f32"}
    assert set(printed["variants"].values()) <= native, printed
    got = read_status(status)
    assert (
        got is not None and got.state == KernelState.ready and got.variants == printed["variants"]
    )
    assert got.finished_at is not None and got.finished_at >= got.started_at


def _client(data_dir: Path) -> TestClient:
    return TestClient(create_app(Settings(data_dir=data_dir, workers=0, render_workers=0)))  # type: ignore[call-arg]


def test_health_and_readiness_report_the_build(tmp_path: Path) -> None:
    data = tmp_path / "data"
    with _client(data) as client:
        body = client.get("/healthz").json()
        assert body["kernels"] is None and body["kernels_detail"] is None  # no local build yet
        started = time.time() - 5
        building = KernelStatus(state=KernelState.building, started_at=started, pid=os.getpid())
        write_status(data / STATUS_FILE, building)
        body = client.get("/healthz").json()
        assert body["status"] == "ok" and body["kernels"] == "building"
        assert body["kernels_detail"].startswith("building the native CPU kernels (")
        ready = client.get("/readyz")
        assert ready.status_code == 503
        assert any(
            p.startswith("building the native CPU kernels") for p in ready.json()["problems"]
        )
        write_status(data / STATUS_FILE, KernelStatus(
            state=KernelState.failed, started_at=started, finished_at=time.time(),
            pid=os.getpid(), message="g++: not found"))  # fmt: skip
        problems = client.get("/readyz").json()["problems"]
        assert "building the native CPU kernels failed: g++: not found" in problems
        write_status(data / STATUS_FILE, KernelStatus(
            state=KernelState.ready, started_at=started, finished_at=time.time(),
            pid=os.getpid(), variants={"rasterizer": "avx2"}))  # fmt: skip
        assert client.get("/healthz").json()["kernels_detail"] == (
            "native CPU kernels ready: rasterizer avx2"
        )
        assert not any("kernels" in p for p in client.get("/readyz").json()["problems"])
