"""The scale-out backend on real processes: Celery worker nodes over a real Redis, job records
in a real PostgreSQL, the API as ``sparsesplat serve``. Two jobs run at once in two worker
processes; a worker process killed mid-training has its job redelivered and finished from its
last checkpoint, once; Redis restarted without persistence loses no queued job; PostgreSQL
restarted makes the API answer 503 meanwhile and everything recovers by itself; a worker node
stopped with SIGTERM hands its job back to be resumed elsewhere.

One service (2 training nodes, 1 render worker) serves the module's tests in turn."""

from __future__ import annotations

import os
import signal
import time
from collections.abc import Iterator
from pathlib import Path

import httpx
import pytest
import sqlalchemy as sa

from sparsesplat.api.store.database import make_engine
from tests.distributed.conftest import celery_env
from tests.distributed.servers import PostgresServer, RedisServer
from tests.service import live as service_live
from tests.service.live import (
    FAST_SPEC,
    TERMINAL,
    LiveService,
    budget_spec,
    submit,
    wait_progress,
    wait_state,
)

pytestmark = pytest.mark.shared_data

TRAIN_NODES = 2
READY_TIMEOUT_S = 420
BUDGET_S = 10.0
"""Training seconds of the jobs a test acts on while they train (kill, stop, keep both nodes
busy): 50-120 iterations ended in under a second of training here, before the test could
act on a fast machine (or before the first 1 s checkpoint it waits for); a budget cannot."""


class Cluster:
    """The service plus handles on its database."""

    def __init__(self, live: LiveService) -> None:
        self.live = live
        self.url = live.url
        self.engine = make_engine(live.env["SPARSESPLAT_DATABASE_URL"])

    def query(self, sql: str, **params: object) -> list[sa.Row]:
        with self.engine.begin() as conn:
            return list(conn.execute(sa.text(sql), params).all())

    def live_train_workers(self) -> list[sa.Row]:
        return self.query(
            "SELECT id, pid, job_id FROM workers WHERE kind='train' AND heartbeat_at > :t",
            t=time.time() - 5,
        )

    def pid_of(self, job_id: str, timeout: float = 60) -> int:
        """Pid of the process that runs ``job_id`` now."""
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            rows = self.query("SELECT pid FROM workers WHERE kind='train' AND job_id=:j", j=job_id)
            if rows:
                return int(rows[0].pid)
            time.sleep(0.1)
        raise TimeoutError(f"no worker registered for {job_id}: {self.live.tail()}")

    def wait_idle_workers(self, n: int = TRAIN_NODES, timeout: float = READY_TIMEOUT_S) -> None:
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            if len([w for w in self.live_train_workers() if w.job_id is None]) >= n:
                return
            time.sleep(0.3)
        raise TimeoutError(f"{n} idle training workers never registered: {self.live.tail()}")


@pytest.fixture(scope="module")
def cluster(
    postgres: PostgresServer, redis_server: RedisServer, tmp_path_factory: pytest.TempPathFactory
) -> Iterator[Cluster]:
    data = tmp_path_factory.mktemp("celery") / "data"
    live = LiveService(data, celery_env(postgres, redis_server))
    cluster = Cluster(live)
    try:
        live.start_api(with_workers=False)
        live.start_workers(train=TRAIN_NODES, render=1)
        # Each pool process imports torch and loads the native extensions before it counts as
        # ready: minutes on a loaded 2-core machine when the extensions need a rebuild.
        live.wait_ready(timeout=READY_TIMEOUT_S)
        cluster.wait_idle_workers()
        yield cluster
    finally:
        live.stop()
        cluster.engine.dispose()


def _states(url: str, job_id: str) -> list[str]:
    events = service_live.job_events(url, job_id)
    return [e["data"]["state"] for e in events if e["type"] == "state"]


def test_two_jobs_run_at_the_same_time_in_two_worker_processes(
    cluster: Cluster, mic_upload: Path
) -> None:
    cluster.wait_idle_workers()
    # Budgets, so that each job trains on while the other is sent and claimed.
    jobs = [submit(cluster.url, mic_upload, budget_spec(BUDGET_S / 2)) for _ in range(2)]
    pids = {job["id"]: cluster.pid_of(job["id"]) for job in jobs}
    assert len(set(pids.values())) == 2, pids
    done = [wait_state(cluster.url, job["id"], TERMINAL) for job in jobs]
    assert [d["state"] for d in done] == ["succeeded", "succeeded"], cluster.live.tail()
    rows = {
        r.id: r
        for r in cluster.query(
            "SELECT id, started_at, finished_at, attempts FROM jobs WHERE id IN (:a, :b)",
            a=jobs[0]["id"],
            b=jobs[1]["id"],
        )
    }
    a, b = (rows[job["id"]] for job in jobs)
    assert a.started_at < b.finished_at and b.started_at < a.finished_at, "they ran one by one"
    assert a.attempts == b.attempts == 1


def test_killed_worker_process_job_is_redelivered_and_resumes_from_its_checkpoint_once(
    cluster: Cluster, mic_upload: Path
) -> None:
    import torch

    cluster.wait_idle_workers()
    job = submit(cluster.url, mic_upload, budget_spec(BUDGET_S))
    checkpoint = cluster.live.data_dir / "jobs" / job["id"] / "run" / "checkpoint.pt"
    wait_progress(cluster.url, job["id"], 20)
    deadline = time.monotonic() + 60
    while not checkpoint.exists():
        assert time.monotonic() < deadline, "no checkpoint was written"
        time.sleep(0.2)
    pid = cluster.pid_of(job["id"])
    os.kill(pid, signal.SIGKILL)  # the Celery pool process running the training
    saved = torch.load(checkpoint, weights_only=False)

    service_live.assert_resumed_once(cluster.url, job["id"], saved, cluster.live.tail)
    # A new pool process took the dead one's place and registered itself.
    cluster.wait_idle_workers()
    assert pid not in {w.pid for w in cluster.live_train_workers()}


def test_stopped_worker_node_hands_its_job_back_and_another_resumes_it(
    cluster: Cluster, mic_upload: Path
) -> None:
    cluster.wait_idle_workers()
    job = submit(cluster.url, mic_upload, budget_spec(BUDGET_S))
    wait_progress(cluster.url, job["id"], 20)
    child = cluster.pid_of(job["id"])
    node = int(Path(f"/proc/{child}/stat").read_text().rsplit(")", 1)[1].split()[1])
    os.kill(node, signal.SIGTERM)  # warm shutdown of the Celery node (docker stop, Ctrl-C)

    done = wait_state(cluster.url, job["id"], TERMINAL, timeout=300)
    assert done["state"] == "succeeded", cluster.live.tail()
    states = [
        (e["data"]["state"], e["data"]["message"])
        for e in service_live.job_events(cluster.url, job["id"])
        if e["type"] == "state"
    ]
    assert [s for s, _ in states] == ["queued", "running", "queued", "running", "succeeded"]
    assert "shut down" in states[2][1] and "attempt 2" in states[3][1], states
    cluster.wait_idle_workers()  # the supervisor started a new node in its place


def test_redis_restarted_mid_queue_every_queued_job_still_runs(
    cluster: Cluster, mic_upload: Path, redis_server: RedisServer
) -> None:
    from sparsesplat.api.settings import load_settings
    from sparsesplat.api.store.broker import make_celery, pending_job_ids

    cluster.wait_idle_workers()
    # Two long jobs occupy both workers; two short ones wait in Redis behind them.
    jobs = [submit(cluster.url, mic_upload, budget_spec(BUDGET_S)) for _ in range(2)]
    jobs += [submit(cluster.url, mic_upload, FAST_SPEC) for _ in range(2)]
    ids = [j["id"] for j in jobs]
    for job_id in ids[:TRAIN_NODES]:
        cluster.pid_of(job_id)
    app = make_celery(load_settings(broker_url=cluster.live.env["SPARSESPLAT_BROKER_URL"]), "t")
    waiting = pending_job_ids(app)
    assert waiting is not None and set(ids[TRAIN_NODES:]) <= waiting, waiting

    redis_server.kill()  # no persistence: every message is gone
    redis_server.start()
    app.close()

    done = [wait_state(cluster.url, job_id, TERMINAL, timeout=300) for job_id in ids]
    assert [d["state"] for d in done] == ["succeeded"] * 4, cluster.live.tail()
    # The waiting jobs ran because the API sent them again, not because a message survived:
    # its log says so for each (reading the empty broker right after the restart raced with
    # that resend, which may come at once when the jobs waited longer than its grace).
    resent = [line for line in cluster.live.log.read_text().splitlines() if "sent again" in line]
    for job_id in ids[TRAIN_NODES:]:
        assert any(job_id in line for line in resent), (job_id, resent)
    assert [d["attempts"] for d in done] == [1] * 4, "each ran once"
    for job_id in ids:
        assert _states(cluster.url, job_id) == ["queued", "running", "succeeded"]


def test_postgresql_restarted_api_answers_503_meanwhile_and_recovers(
    cluster: Cluster, mic_upload: Path, postgres: PostgresServer
) -> None:
    cluster.wait_idle_workers()
    running = submit(cluster.url, mic_upload, {**FAST_SPEC, "iterations": 120})
    wait_progress(cluster.url, running["id"], 10)

    postgres.stop()
    try:
        answer = httpx.get(f"{cluster.url}/v1/jobs/{running['id']}", timeout=30)
        assert answer.status_code == 503, answer.text
        body = answer.json()
        assert body["code"] == "database_unavailable" and "database" in body["message"]
        assert answer.headers.get("retry-after")
        assert httpx.get(f"{cluster.url}/healthz", timeout=10).status_code == 200
        ready = httpx.get(f"{cluster.url}/readyz", timeout=30)
        assert ready.status_code == 503 and ready.json()["database"] is False
        time.sleep(2.0)
    finally:
        postgres.start()

    deadline = time.monotonic() + 60  # recovers by itself: no restart of anything
    while httpx.get(f"{cluster.url}/v1/jobs/{running['id']}", timeout=30).status_code != 200:
        assert time.monotonic() < deadline, "the API did not recover"
        time.sleep(0.3)
    later = submit(cluster.url, mic_upload, FAST_SPEC)  # and takes new work
    for job in (running, later):
        done = wait_state(cluster.url, job["id"], TERMINAL, timeout=300)
        assert done["state"] == "succeeded", (done, cluster.live.tail())
        events = service_live.job_events(cluster.url, job["id"])
        seqs = [e["seq"] for e in events]
        assert seqs == list(range(1, len(seqs) + 1)), "an event was lost or repeated"
    cluster.wait_idle_workers()
