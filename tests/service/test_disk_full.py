"""A full disk at every write site, on the real processes: writes are made to fail with ENOSPC
(or SQLite to report a full database) through the test-only rules file the service reads
(``sparsesplat.api.faults``), switched on and off while it runs.

At each site the job (or request) fails naming the cause, no partial file remains, the job
state is consistent (never ``running`` for good), a model trained earlier still renders, and
the next job runs once the space is back."""

from __future__ import annotations

from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

import httpx
import pytest

from tests.service.disk import Faults, partial_files, renders, wait_for
from tests.service.live import (
    FAST_SPEC,
    TERMINAL,
    LiveService,
    submit,
    upload_parts,
    wait_state,
)

pytestmark = pytest.mark.shared_data

NO_SPACE = "no space left on device"


@pytest.fixture
def faults(tmp_path: Path) -> Faults:
    return Faults(tmp_path / "faults")


def _service(tmp_path: Path, faults: Faults, **settings: str) -> LiveService:
    env = {
        **faults.env(),
        "SPARSESPLAT_DISK_RESERVE_MB": "1",
        **{f"SPARSESPLAT_{k.upper()}": v for k, v in settings.items()},
    }
    return LiveService(tmp_path / "data", env)


@contextmanager
def _ready_service(tmp_path: Path, faults: Faults, **settings: str) -> Iterator[LiveService]:
    """The service of :func:`_service` with its workers, ready for jobs; stopped after."""
    live = _service(tmp_path, faults, **settings)
    try:
        live.start_api()
        live.wait_ready()
        yield live
    finally:
        live.stop()


def _post_job(url: str, folder: Path) -> httpx.Response:
    return httpx.post(url + "/v1/jobs", files=upload_parts(folder, FAST_SPEC), timeout=60)


def test_uploads_and_the_job_database_refuse_with_507_and_keep_nothing(
    tmp_path: Path, faults: Faults, mic_upload: Path
) -> None:
    live = _service(tmp_path, faults)
    try:
        live.start_api(with_workers=False)
        staging = live.data_dir / "staging"

        # Upload staging: the files cannot be written.
        faults.set("enospc */staging/*")
        answer = _post_job(live.url, mic_upload)
        assert answer.status_code == 507, answer.text
        assert answer.json()["code"] == "insufficient_storage"
        assert answer.json()["message"].startswith(f"{NO_SPACE} while receiving the upload")

        # The SQLite commit of the job record.
        faults.set("sqlite INSERT INTO jobs*")
        answer = _post_job(live.url, mic_upload)
        assert answer.status_code == 507, answer.text
        assert f"{NO_SPACE} while committing to the job database" in answer.json()["message"]

        # Less free than the upload needs: refused before anything is read.
        faults.set("free 100000")
        answer = _post_job(live.url, mic_upload)
        assert answer.status_code == 507, answer.text
        assert "needs ~" in answer.json()["message"] and "0.1 MB free" in answer.json()["message"]
        health = httpx.get(live.url + "/healthz").json()
        assert health["disk"] == "full" and health["disk_free_bytes"] <= 100000

        # Nothing was kept: no job, no folder, no staged file; and with space back it works.
        assert httpx.get(live.url + "/v1/jobs").json()["jobs"] == []
        assert list((live.data_dir / "jobs").iterdir()) == []
        assert list(staging.iterdir()) == [] and partial_files(live.data_dir) == []
        faults.set()
        assert httpx.get(live.url + "/healthz").json()["disk"] == "ok"
        job = _post_job(live.url, mic_upload).json()

        # DELETE on a full database frees the files all the same (507: the record stays until
        # a retry, which succeeds once the database has room).
        faults.set("sqlite DELETE FROM events*")
        answer = httpx.delete(f"{live.url}/v1/jobs/{job['id']}")
        assert answer.status_code == 507, answer.text
        assert not (live.data_dir / "jobs" / job["id"]).exists()
        faults.set()
        assert httpx.delete(f"{live.url}/v1/jobs/{job['id']}").status_code == 204
        assert httpx.get(f"{live.url}/v1/jobs/{job['id']}").status_code == 404
    finally:
        live.stop()


def _fails_at(live: LiveService, folder: Path, site: str, model_id: str) -> dict:
    """Submit a job (the fault is in force): it fails naming ``site``; nothing partial stays,
    nor its checkpoint or exports; the earlier model renders."""
    job = submit(live.url, folder, FAST_SPEC)
    done = wait_state(live.url, job["id"], TERMINAL, timeout=240)
    assert done["state"] == "failed", (site, done, live.tail())
    assert done["error"].startswith(f"{NO_SPACE} while {site}"), done["error"]
    run = live.data_dir / "jobs" / job["id"] / "run"
    assert partial_files(live.data_dir) == []
    assert not any((run / name).exists() for name in ("checkpoint.pt", "model.ply", "model.splat"))
    renders(live.url, model_id)
    return done


def test_a_full_disk_at_each_write_of_a_job_fails_it_naming_the_write(
    tmp_path: Path, faults: Faults, mic_upload: Path
) -> None:
    with _ready_service(tmp_path, faults) as live:
        earlier = submit(live.url, mic_upload, FAST_SPEC)
        assert wait_state(live.url, earlier["id"], TERMINAL)["state"] == "succeeded"

        faults.set("enospc */run/checkpoint.pt.tmp")
        done = _fails_at(
            live, mic_upload, "writing the training checkpoint (needs ~", earlier["id"]
        )
        assert "MB free)" in done["error"]
        faults.set("enospc */run/model.ply")
        _fails_at(live, mic_upload, "writing the exports (model.ply, model.splat)", earlier["id"])
        faults.set("enospc */run/model.pt.tmp")
        _fails_at(live, mic_upload, "saving the final model (needs ~", earlier["id"])

        # Space is back: the next job runs on the same worker (it never died).
        faults.set()
        after = submit(live.url, mic_upload, FAST_SPEC)
        assert wait_state(live.url, after["id"], TERMINAL)["state"] == "succeeded"
        assert partial_files(live.data_dir) == []


def test_a_full_job_database_mid_job_fails_it_once_space_returns(
    tmp_path: Path, faults: Faults, mic_upload: Path
) -> None:
    with _ready_service(tmp_path, faults, disk_wait_s="120") as live:
        earlier = submit(live.url, mic_upload, FAST_SPEC)
        assert wait_state(live.url, earlier["id"], TERMINAL)["state"] == "succeeded"
        job = submit(live.url, mic_upload, {**FAST_SPEC, "iterations": 3000})
        queued = submit(live.url, mic_upload, FAST_SPEC)
        wait_for(
            lambda: (httpx.get(f"{live.url}/v1/jobs/{job['id']}").json().get("progress") or {})
            .get("iteration", 0) > 0,
            180, "the long job trains",
        )  # fmt: skip

        # Every event (records, progress, state changes) now fails as on a full disk: the job
        # cannot report, nor store its outcome. Reads and renders go on.
        faults.set("sqlite INSERT INTO events*")
        wait_for(lambda: "cannot store the job's outcome yet" in live.tail(20000), 60,
                 "the worker waits to store the outcome")  # fmt: skip
        assert httpx.get(f"{live.url}/v1/jobs/{job['id']}").json()["state"] == "running"
        renders(live.url, earlier["id"])
        assert partial_files(live.data_dir) == []

        faults.set()  # space returns
        done = wait_state(live.url, job["id"], TERMINAL, timeout=60)
        assert done["state"] == "failed" and done["attempts"] == 1, done
        assert done["error"].startswith(f"{NO_SPACE} while committing to the job database")
        assert wait_state(live.url, queued["id"], TERMINAL)["state"] == "succeeded"
        assert "heartbeat failed: the disk holding the job database is full" in live.tail(10**6)


def test_a_job_that_does_not_fit_waits_for_space_then_starts_or_fails(
    tmp_path: Path, faults: Faults, mic_upload: Path
) -> None:
    with _ready_service(tmp_path, faults, disk_wait_s="6") as live:
        faults.set("free 3000000")  # 3 MB: under any job's expected bytes

        # Space returns while it waits: it starts, and the job behind it too.
        first = submit(live.url, mic_upload, FAST_SPEC)
        second = submit(live.url, mic_upload, FAST_SPEC)
        waiting = wait_for(
            lambda: [w for w in httpx.get(f"{live.url}/v1/jobs/{first['id']}").json()["warnings"]
                     if w.startswith("waiting for disk space")],
            30, "the job waits for space",
        )  # fmt: skip
        assert "MB are free" in waiting[0] and "needs ~" in waiting[0]
        assert httpx.get(f"{live.url}/v1/jobs/{first['id']}").json()["state"] == "queued"
        assert httpx.get(live.url + "/healthz").json()["disk"] in ("low", "ok", "full")
        faults.set()
        for job in (first, second):
            assert wait_state(live.url, job["id"], TERMINAL)["state"] == "succeeded"

        # Space does not return: it fails after the wait, naming what it needs and has.
        faults.set("free 3000000")
        third = submit(live.url, mic_upload, FAST_SPEC)
        done = wait_state(live.url, third["id"], TERMINAL, timeout=60)
        assert done["state"] == "failed" and done["attempts"] == 0
        assert done["error"].startswith(f"{NO_SPACE} to start this job (needs ~")
        assert "3.0 MB free; waited 6 s" in done["error"]
        renders(live.url, first["id"])
