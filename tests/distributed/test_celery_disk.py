"""A full disk on the scale-out backend (Celery + PostgreSQL): the task of a job that does not
fit waits for space and runs once it returns; a checkpoint that cannot be written fails the
job naming it, as with the embedded queue (tests/service/test_disk_full.py)."""

from __future__ import annotations

from pathlib import Path

import httpx
import pytest

from tests.distributed.conftest import celery_env
from tests.distributed.servers import PostgresServer, RedisServer
from tests.service.disk import Faults, partial_files, wait_for
from tests.service.live import FAST_SPEC, TERMINAL, LiveService, submit, wait_state

pytestmark = pytest.mark.shared_data


def test_celery_jobs_wait_for_space_and_fail_naming_a_full_write(
    tmp_path: Path, postgres: PostgresServer, redis_server: RedisServer, mic_upload: Path
) -> None:
    faults = Faults(tmp_path / "faults")
    env = {**celery_env(postgres, redis_server), **faults.env(), "SPARSESPLAT_DISK_RESERVE_MB": "1"}
    live = LiveService(tmp_path / "data", env)
    try:
        live.start_api(with_workers=False)
        live.start_workers(train=1, render=1)
        live.wait_ready(timeout=600)

        faults.set("free 3000000")
        job = submit(live.url, mic_upload, FAST_SPEC)
        wait_for(
            lambda: any(w.startswith("waiting for disk space") for w in
                        httpx.get(f"{live.url}/v1/jobs/{job['id']}").json()["warnings"]),
            120, "the job waits for space",
        )  # fmt: skip
        assert httpx.get(f"{live.url}/v1/jobs/{job['id']}").json()["state"] == "queued"
        faults.set()
        assert wait_state(live.url, job["id"], TERMINAL)["state"] == "succeeded", live.tail()

        faults.set("enospc */run/checkpoint.pt.tmp")
        failing = submit(live.url, mic_upload, FAST_SPEC)
        done = wait_state(live.url, failing["id"], TERMINAL)
        assert done["state"] == "failed", live.tail()
        assert done["error"].startswith("no space left on device while writing the training")
        assert partial_files(live.data_dir) == []
    finally:
        live.stop()
