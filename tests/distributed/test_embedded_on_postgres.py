"""The embedded backend (table queue, local worker processes) with its job records in
PostgreSQL: a database restart in the middle of a job pauses the job's writes instead of
failing its attempt, as on the Celery backend."""

from __future__ import annotations

import time
import uuid
from pathlib import Path

import httpx
import pytest

from tests.distributed.servers import PostgresServer
from tests.service.live import (
    FAST_SPEC,
    TERMINAL,
    LiveService,
    job_events,
    submit,
    wait_progress,
    wait_state,
)

pytestmark = pytest.mark.shared_data

OUTAGE_S = 2.0
"""How long PostgreSQL stays down (well inside the lease below)."""


def test_postgresql_restart_mid_job_pauses_the_job_instead_of_failing_it(
    postgres: PostgresServer, mic_upload: Path, tmp_path: Path
) -> None:
    database = postgres.create_database(f"embedded_{uuid.uuid4().hex[:8]}")
    live = LiveService(
        tmp_path / "data",
        # A lease longer than the outage: the job keeps it, so nothing re-queues it meanwhile
        # and attempts must stay at 1.
        {"SPARSESPLAT_DATABASE_URL": database, "SPARSESPLAT_LEASE_S": "30"},
    )
    try:
        live.start_api()
        live.wait_ready(timeout=420)
        spec = {**FAST_SPEC, "iterations": 600, "record_interval_s": 0.3}
        job = submit(live.url, mic_upload, spec)
        wait_progress(live.url, job["id"], 10)
        postgres.stop()
        try:
            time.sleep(OUTAGE_S)
        finally:
            postgres.start()
        done = wait_state(live.url, job["id"], TERMINAL, timeout=300)
        assert done["state"] == "succeeded", (done, live.tail())
        assert done["attempts"] == 1, "the outage failed the attempt"
        seqs = [e["seq"] for e in job_events(live.url, job["id"])]
        assert seqs == list(range(1, len(seqs) + 1)), "an event was lost or repeated"
        answer = httpx.get(f"{live.url}/v1/jobs/{job['id']}", timeout=30)
        assert answer.status_code == 200
    finally:
        live.stop()
