"""A real service for tests: ``sparsesplat serve`` / ``sparsesplat worker`` as subprocesses on
127.0.0.1, with a temporary data directory and short leases so failures resolve in seconds."""

from __future__ import annotations

import contextlib
import json
import os
import signal
import socket
import subprocess
import sys
import time
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import httpx
from websockets.sync.client import connect

FAST_SETTINGS = {
    "SPARSESPLAT_HEARTBEAT_S": "0.5",
    "SPARSESPLAT_LEASE_S": "4",
    "SPARSESPLAT_POLL_S": "0.3",
    "SPARSESPLAT_CANCEL_GRACE_S": "10",
    "SPARSESPLAT_CHECKPOINT_INTERVAL_S": "1",
    "SPARSESPLAT_LOG_JSON": "false",
    "SPARSESPLAT_TORCH_THREADS": "1",
    "SPARSESPLAT_RENDER_THREADS": "1",
}
"""Settings that make a test service fail over quickly."""

FAST_SPEC = {"iterations": 30, "record_interval_s": 2.0, "depth_prior": "none", "color_model": "sh"}
"""A job that trains in seconds (no prior, SH colour); for tests about the service."""


def budget_spec(seconds: float) -> dict[str, Any]:
    """:data:`FAST_SPEC` trained for ``seconds`` training seconds instead of a count of
    iterations: for tests that act on a job while it trains (kill, stop, cancel, delete). A
    count that lasts long enough on a slow machine can end on a fast one before the test acts
    (a quiet CI machine trains a few hundred mic iterations a second); a budget cannot."""
    return {k: v for k, v in FAST_SPEC.items() if k != "iterations"} | {"time_budget_s": seconds}


def free_port() -> int:
    """A TCP port nobody listens on right now."""
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def answers(url: str, timeout: float, pause: float, alive: Callable[[], None]) -> bool:
    """Poll ``url`` every ``pause`` s until it answers 200 (True) or ``timeout`` passes (False);
    ``alive`` runs before each try and raises when the server process has died."""
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        alive()
        try:
            if httpx.get(url, timeout=2).status_code == 200:
                return True
        except httpx.TransportError:
            pass
        time.sleep(pause)
    return False


class LiveService:
    """The API and/or worker processes over one data directory."""

    def __init__(self, data_dir: Path, env: dict[str, str] | None = None) -> None:
        self.data_dir = data_dir
        self.port = free_port()
        self.url = f"http://127.0.0.1:{self.port}"
        self.env = {
            **os.environ,
            **FAST_SETTINGS,
            "SPARSESPLAT_DATA_DIR": str(data_dir),
            "SPARSESPLAT_PORT": str(self.port),
            **(env or {}),
        }
        self.api: subprocess.Popen[bytes] | None = None
        self.workers: subprocess.Popen[bytes] | None = None
        self.log = data_dir.parent / f"service-{self.port}.log"

    def _spawn(self, *args: str) -> subprocess.Popen[bytes]:
        out = self.log.open("ab")
        return subprocess.Popen(
            [sys.executable, "-m", "sparsesplat.client.cli", *args],
            env=self.env, stdout=out, stderr=subprocess.STDOUT, start_new_session=True,
        )  # fmt: skip

    def start_api(self, with_workers: bool = True) -> None:
        """``sparsesplat serve`` (its own workers unless ``with_workers`` is False)."""
        args = ["serve"] if with_workers else ["serve", "--workers", "0", "--render-workers", "0"]
        self.api = self._spawn(*args)
        self.wait_healthy()

    def start_workers(self, train: int = 1, render: int = 1) -> None:
        """``sparsesplat worker`` beside an API started without workers."""
        self.workers = self._spawn("worker", "--train", str(train), "--render", str(render))

    def wait_healthy(self, timeout: float = 60) -> None:
        """Until ``/healthz`` answers."""
        if not self._answers("/healthz", timeout, 0.2, watch_api=True):
            raise TimeoutError(f"server not healthy after {timeout} s: {self.tail()}")

    def wait_ready(self, timeout: float = 120) -> None:
        """Until ``/readyz`` says a training and a render worker are up."""
        if not self._answers("/readyz", timeout, 0.3, watch_api=False):
            raise TimeoutError(f"service not ready after {timeout} s: {self.tail()}")

    def _answers(self, path: str, timeout: float, pause: float, watch_api: bool) -> bool:
        """:func:`answers` for ``path``; with ``watch_api``, an API process that exited raises
        at once."""

        def alive() -> None:
            if watch_api and self.api is not None and self.api.poll() is not None:
                raise RuntimeError(f"server exited with {self.api.returncode}: {self.tail()}")

        return answers(self.url + path, timeout, pause, alive)

    def kill_api(self) -> None:
        """SIGKILL the API process (its workers, if separate, keep running)."""
        assert self.api is not None
        self.api.kill()
        self.api.wait()

    def stop(self) -> None:
        """Stop everything this object started (whole process groups)."""
        for proc in (self.api, self.workers):
            if proc is not None and proc.poll() is None:
                os.killpg(proc.pid, signal.SIGTERM)
        for proc in (self.api, self.workers):
            if proc is None:
                continue
            with contextlib.suppress(subprocess.TimeoutExpired):
                proc.wait(timeout=30)
            # Whatever is left of the group (a supervisor or worker still busy) goes too.
            with contextlib.suppress(ProcessLookupError):
                os.killpg(proc.pid, signal.SIGKILL)
            proc.wait()

    def tail(self, n: int = 3000) -> str:
        """The end of the service log (for failure messages)."""
        return self.log.read_text(errors="replace")[-n:] if self.log.exists() else ""


def upload_parts(folder: Path, spec: dict[str, Any]) -> list[tuple[str, Any]]:
    """Multipart parts of ``POST /v1/jobs`` for an upload folder (cameras.json + images)."""
    cameras = json.loads((folder / "cameras.json").read_text())
    parts: list[tuple[str, Any]] = [
        ("cameras", ("cameras.json", (folder / "cameras.json").read_bytes(), "application/json")),
        ("spec", (None, json.dumps(spec))),
    ]
    for frame in cameras["frames"]:
        path = folder / frame["image"]
        parts.append(("images", (path.name, path.read_bytes(), "image/png")))
    return parts


def submit(url: str, folder: Path, spec: dict[str, Any], **headers: str) -> dict[str, Any]:
    """Submit a job; returns the job (asserts 201)."""
    response = httpx.post(url + "/v1/jobs", files=upload_parts(folder, spec), headers=headers,
                          timeout=60)  # fmt: skip
    assert response.status_code == 201, response.text
    return dict(response.json())


def wait_state(url: str, job_id: str, states: set[str], timeout: float = 300) -> dict[str, Any]:
    """Poll until the job is in one of ``states``."""
    deadline = time.monotonic() + timeout
    job: dict[str, Any] = {}
    while time.monotonic() < deadline:
        job = httpx.get(f"{url}/v1/jobs/{job_id}", timeout=10).json()
        if job.get("state") in states:
            return job
        time.sleep(0.3)
    raise TimeoutError(f"job {job_id} still {job.get('state')} after {timeout} s: {job}")


TERMINAL = {"succeeded", "failed", "cancelled"}
"""The job states that end a job."""


def wait_progress(url: str, job_id: str, iteration: int, timeout: float = 180) -> dict[str, Any]:
    """Poll until the job reports ``iteration`` or more (a job that ends first fails the
    test); returns the job as then read."""
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        job = httpx.get(f"{url}/v1/jobs/{job_id}", timeout=10).json()
        if (job.get("progress") or {}).get("iteration", 0) >= iteration:
            return dict(job)
        assert job["state"] not in TERMINAL, job
        time.sleep(0.2)
    raise TimeoutError(f"job {job_id} did not reach iteration {iteration}")


def job_events(url: str, job_id: str) -> list[dict[str, Any]]:
    """Every stored event of a finished job (the stream closes after the terminal state)."""
    ws_url = url.replace("http://", "ws://") + f"/v1/jobs/{job_id}/events?after=0"
    with connect(ws_url, open_timeout=30) as ws:
        return [json.loads(m) for m in ws]


def assert_resumed_once(
    url: str, job_id: str, checkpoint: dict[str, Any], tail: Callable[[], str]
) -> list[int]:
    """The time-budget job (:func:`budget_spec`) whose worker was killed after writing
    ``checkpoint`` (its loaded state) ends succeeded on attempt 2: requeued once ("stopped
    answering"), resumed, and the second attempt continues from the checkpoint, never from
    zero: its iterations and its budget's clock go on from the saved ones, and it stops when
    the budget is spent in all (not a whole budget after the resume). Returns the iterations
    reported after the resume; ``tail`` gives the service log for a failure message."""
    saved, saved_s = int(checkpoint["iteration"]), float(checkpoint["elapsed_s"])
    done = wait_state(url, job_id, TERMINAL, timeout=300)
    assert done["state"] == "succeeded", tail()
    assert done["attempts"] == 2, "run once more, not twice more"
    events = job_events(url, job_id)
    states = [(e["data"]["state"], e["data"]["message"]) for e in events if e["type"] == "state"]
    assert [s for s, _ in states] == ["queued", "running", "queued", "running", "succeeded"]
    assert "stopped answering" in states[2][1] and "attempt 2" in states[3][1]
    resumed_at = next(
        i for i, e in enumerate(events) if e["data"].get("message", "").startswith("resumed")
    )
    after = [e["data"]["iteration"] for e in events[resumed_at:] if e["type"] == "progress"]
    # The heartbeat may publish the resumed trainer's iteration (= saved) before its first
    # step; never anything below it.
    assert after and min(after) >= saved >= 1 and max(after) > saved, (saved, after[:5])
    clock = [e["data"]["elapsed_s"] for e in events[resumed_at:] if e["type"] == "progress"]
    assert min(clock) >= saved_s > 0, (saved_s, clock[:5])
    budget, spent = float(done["spec"]["time_budget_s"]), done["progress"]["elapsed_s"]
    # Trained until the budget was spent, counting the first attempt's seconds: a second
    # attempt that started the budget afresh would end past saved_s + budget.
    assert budget <= spent < saved_s + budget, (saved_s, budget, spent)
    return after


def processes_of(service: LiveService) -> Iterator[int]:
    """Pids of training workers registered in the database."""
    import sqlalchemy as sa

    engine = sa.create_engine(f"sqlite:///{service.data_dir / 'sparsesplat.db'}")
    with engine.begin() as conn:
        rows = conn.execute(sa.text("SELECT pid, job_id FROM workers WHERE kind='train'")).all()
    engine.dispose()
    for pid, _job in rows:
        yield int(pid)
