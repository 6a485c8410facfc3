"""The scale-out backend with the job files in a bucket (moto's S3 server on loopback): the
API and the Celery worker node share nothing but PostgreSQL, Redis and the bucket (each its
own data folder, as on two machines). A job runs end to end and is served from the bucket;
a worker process killed mid-training (``kill -9``), whose machine's copy of the job is gone
too, has its job resumed from the checkpoint in the bucket, once."""

from __future__ import annotations

import os
import shutil
import signal
import time
from collections.abc import Iterator
from pathlib import Path

import httpx
import pytest
import sqlalchemy as sa

from sparsesplat.api.store.database import make_engine
from tests.artifacts.moto_s3 import MotoS3
from tests.distributed.conftest import celery_env
from tests.distributed.servers import PostgresServer, RedisServer
from tests.service import live as service_live
from tests.service.disk import renders
from tests.service.live import FAST_SPEC, TERMINAL, LiveService, budget_spec, submit, wait_state

pytestmark = pytest.mark.shared_data

READY_TIMEOUT_S = 420


class SharedNothing:
    """The API on one data folder, a Celery worker node on another, one bucket."""

    def __init__(self, root: Path, env: dict[str, str], s3: MotoS3, bucket: str) -> None:
        for machine in ("api", "worker"):
            (root / machine).mkdir()
        self.s3, self.bucket = s3, bucket
        self.api = LiveService(root / "api" / "data", env)
        self.worker = LiveService(root / "worker" / "data", env)
        self.url = self.api.url
        self.engine = make_engine(env["SPARSESPLAT_DATABASE_URL"])

    def tail(self) -> str:
        return f"API: {self.api.tail()}\nworker: {self.worker.tail()}"

    def pid_of(self, job_id: str, timeout: float = 60) -> int:
        """Pid of the pool process that runs ``job_id`` now."""
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            with self.engine.begin() as conn:
                rows = conn.execute(
                    sa.text("SELECT pid FROM workers WHERE kind='train' AND job_id=:j"),
                    {"j": job_id},
                ).all()
            if rows:
                return int(rows[0].pid)
            time.sleep(0.1)
        raise TimeoutError(f"no worker registered for {job_id}: {self.tail()}")

    def wait_idle_worker(self, timeout: float = READY_TIMEOUT_S) -> None:
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            with self.engine.begin() as conn:
                idle = conn.execute(
                    sa.text("SELECT count(*) FROM workers WHERE kind='train' AND job_id IS NULL "
                            "AND heartbeat_at > :t"), {"t": time.time() - 5},
                ).scalar_one()  # fmt: skip
            if idle:
                return
            time.sleep(0.3)
        raise TimeoutError(f"no idle training worker: {self.tail()}")

    def objects(self, job_id: str) -> dict[str, int]:
        return self.s3.objects(self.bucket, f"deploy/jobs/{job_id}/")


@pytest.fixture(scope="module")
def cluster(
    postgres: PostgresServer,
    redis_server: RedisServer,
    s3: MotoS3,
    tmp_path_factory: pytest.TempPathFactory,
) -> Iterator[SharedNothing]:
    bucket = s3.new_bucket()
    env = celery_env(postgres, redis_server) | s3.settings_env(bucket)
    cluster = SharedNothing(tmp_path_factory.mktemp("celery-s3"), env, s3, bucket)
    try:
        cluster.api.start_api(with_workers=False)
        cluster.worker.start_workers(train=1, render=1)
        cluster.api.wait_ready(timeout=READY_TIMEOUT_S)
        cluster.wait_idle_worker()
        yield cluster
    finally:
        cluster.worker.stop()
        cluster.api.stop()
        cluster.engine.dispose()


def test_a_job_runs_end_to_end_with_no_shared_folder(
    cluster: SharedNothing, mic_upload: Path
) -> None:
    cluster.wait_idle_worker()
    job = submit(cluster.url, mic_upload, {**FAST_SPEC, "iterations": 40})
    done = wait_state(cluster.url, job["id"], TERMINAL)
    assert done["state"] == "succeeded", cluster.tail()
    stored = cluster.objects(job["id"])
    run = f"deploy/jobs/{job['id']}/run/"
    assert {run + "checkpoint.pt", run + "model.ply", run + "model.splat"} <= set(stored)
    # The API never saw the run's files on its own disk: it serves them from the bucket.
    api_job = cluster.api.data_dir / "jobs" / job["id"]
    assert not (api_job / "run").exists()
    splat = httpx.get(f"{cluster.url}/v1/models/{job['id']}/export/splat", timeout=60)
    assert splat.status_code == 200 and len(splat.content) == stored[run + "model.splat"]
    assert renders(cluster.url, job["id"]).startswith(b"\x89PNG")
    usage = httpx.get(f"{cluster.url}/v1/usage", timeout=30).json()
    assert usage["stored_bytes"] >= sum(stored.values())


def test_killed_worker_resumes_from_the_checkpoint_in_the_bucket(
    cluster: SharedNothing, mic_upload: Path, tmp_path: Path
) -> None:
    import torch

    cluster.wait_idle_worker()
    # A budget: 100 iterations ended in under a second of training, before the first 1 s
    # checkpoint on a fast machine (the one the test waited for was then the final one).
    job = submit(cluster.url, mic_upload, budget_spec(10.0))
    key = f"deploy/jobs/{job['id']}/run/checkpoint.pt"
    deadline = time.monotonic() + 180
    while key not in cluster.objects(job["id"]):
        assert time.monotonic() < deadline, f"no checkpoint reached the bucket: {cluster.tail()}"
        time.sleep(0.2)
    pid = cluster.pid_of(job["id"])
    os.kill(pid, signal.SIGKILL)  # the Celery pool process running the training
    # The worker machine's copy goes too (within the 4 s lease, before anyone resumes): the
    # next attempt has only the bucket to resume from.
    shutil.rmtree(cluster.worker.data_dir / "jobs" / job["id"])
    cluster.s3.client().download_file(cluster.bucket, key, str(tmp_path / "saved.pt"))
    saved = torch.load(tmp_path / "saved.pt", weights_only=False)

    service_live.assert_resumed_once(cluster.url, job["id"], saved, cluster.tail)
    assert (cluster.worker.data_dir / "jobs" / job["id"] / "upload" / "cameras.json").is_file()
