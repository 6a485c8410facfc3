"""The service with its job files in a bucket (moto's S3 server on loopback), on real
processes: the API and the workers share no folder (each its own data folder, as on two
machines; the SQLite job database stands in for PostgreSQL). The API killed mid-job and
restarted on an empty disk loses nothing: the job finishes, and its images, exports, renders
and usage come from the bucket; DELETE empties the bucket of it. A refused credential fails
the API at start and a job at its worker, naming the cause, and loses nothing stored."""

from __future__ import annotations

import json
import shutil
import time
from collections.abc import Iterator
from pathlib import Path

import httpx
import pytest

from tests.artifacts.moto_s3 import MotoS3
from tests.service.disk import renders
from tests.service.live import FAST_SPEC, TERMINAL, LiveService, submit, wait_progress, wait_state
from tests.service.scenes import MIC, write_mic_upload

pytestmark = pytest.mark.shared_data

READY_TIMEOUT_S = 420
"""Worker processes import torch and check the native kernels first: minutes on a loaded
2-core machine."""


@pytest.fixture(scope="module")
def mic_upload(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """3 training + 2 held-out views of the shared Blender mic, 100x100."""
    if not MIC.is_dir():
        pytest.skip(f"shared scene missing: {MIC}")
    return write_mic_upload(tmp_path_factory.mktemp("mic") / "upload", size=100)


class Machines:
    """An API and a worker node, each with its own data folder, on one bucket."""

    def __init__(self, root: Path, s3: MotoS3, bucket: str, worker_env: dict[str, str]) -> None:
        env = s3.settings_env(bucket) | {
            "SPARSESPLAT_DATABASE_URL": f"sqlite:///{root / 'jobs.db'}"
        }
        for machine in ("api", "worker"):
            (root / machine).mkdir(exist_ok=True)
        self.api = LiveService(root / "api" / "data", env)
        self.worker = LiveService(root / "worker" / "data", env | worker_env)
        self.worker.url = self.api.url  # the worker node serves no HTTP API of its own

    def start(self) -> None:
        self.api.start_api(with_workers=False)
        self.worker.start_workers(train=1, render=1)
        self.api.wait_ready(timeout=READY_TIMEOUT_S)

    def stop(self) -> None:
        self.worker.stop()
        self.api.stop()

    def tail(self) -> str:
        return f"API: {self.api.tail()}\nworker: {self.worker.tail()}"


@pytest.fixture
def bucket(s3: MotoS3) -> str:
    return s3.new_bucket()


@pytest.fixture
def machines(tmp_path: Path, s3: MotoS3, bucket: str) -> Iterator[Machines]:
    m = Machines(tmp_path, s3, bucket, {})
    yield m
    m.stop()


def _frame_bytes(upload: Path, index: int) -> bytes:
    """The bytes of the ``index``-th frame's image as it was uploaded."""
    frames = json.loads((upload / "cameras.json").read_text())["frames"]
    return (upload / frames[index]["image"]).read_bytes()


def test_api_restarted_on_an_empty_disk_mid_job_loses_nothing(
    machines: Machines, s3: MotoS3, bucket: str, mic_upload: Path
) -> None:
    machines.start()
    api = machines.api
    job = submit(api.url, mic_upload, {**FAST_SPEC, "iterations": 150})
    prefix = f"deploy/jobs/{job['id']}/"
    uploaded = s3.objects(bucket, prefix + "upload/")
    assert prefix + "upload/cameras.json" in uploaded and len(uploaded) == 1 + 5, uploaded
    wait_progress(api.url, job["id"], 10)

    api.kill_api()
    shutil.rmtree(api.data_dir / "jobs")  # the API's machine comes back with nothing on disk
    time.sleep(1.0)  # the job trains on meanwhile
    api.start_api(with_workers=False)
    done = wait_state(api.url, job["id"], TERMINAL)
    assert done["state"] == "succeeded", machines.tail()
    assert not (api.data_dir / "jobs" / job["id"] / "run").exists(), "the API shares a folder"

    stored = s3.objects(bucket, prefix)
    assert {f"{prefix}run/{name}" for name in ("checkpoint.pt", "model.ply", "model.splat")} <= set(
        stored
    ), stored
    assert not [k for k in stored if ".tmp" in k or ("/priors/" in k and "view_" not in k)]

    image = httpx.get(f"{api.url}/v1/jobs/{job['id']}/images/0", timeout=30)
    assert image.status_code == 200
    assert image.content == _frame_bytes(mic_upload, 0)
    info = httpx.get(f"{api.url}/v1/models/{job['id']}", timeout=30).json()
    assert set(info["exports"]) == {"ply", "splat", "checkpoint"}
    ply = httpx.get(f"{api.url}/v1/models/{job['id']}/export/ply", timeout=60)
    assert ply.status_code == 200 and len(ply.content) == stored[f"{prefix}run/model.ply"]
    assert renders(api.url, job["id"]).startswith(b"\x89PNG")
    usage = httpx.get(f"{api.url}/v1/usage", timeout=30).json()
    assert usage["stored_bytes"] == sum(stored.values())

    assert httpx.delete(f"{api.url}/v1/jobs/{job['id']}", timeout=30).status_code == 204
    assert s3.objects(bucket, prefix) == {}
    assert httpx.get(f"{api.url}/v1/usage", timeout=30).json()["stored_bytes"] == 0


def test_a_refused_credential_is_named_and_loses_nothing(
    tmp_path: Path, s3: MotoS3, bucket: str, mic_upload: Path
) -> None:
    wrong = {"SPARSESPLAT_S3_SECRET_ACCESS_KEY": "not-the-secret"}
    # The API checks the bucket as it starts: it stops at once, saying why.
    (tmp_path / "refused").mkdir()
    refused = LiveService(tmp_path / "refused" / "data", s3.settings_env(bucket) | wrong)
    try:
        with pytest.raises(RuntimeError, match="server exited"):
            refused.start_api(with_workers=False)
        assert "refused the credentials (SignatureDoesNotMatch" in refused.tail(20000)
    finally:
        refused.stop()

    # A worker given a wrong secret fails the job, naming the cause; the upload stays stored.
    machines = Machines(tmp_path, s3, bucket, wrong)
    try:
        machines.start()
        job = submit(machines.api.url, mic_upload, FAST_SPEC)
        uploaded = s3.objects(bucket, f"deploy/jobs/{job['id']}/")
        done = wait_state(machines.api.url, job["id"], TERMINAL)
        assert done["state"] == "failed", machines.tail()
        assert "refused the credentials (SignatureDoesNotMatch" in done["error"]
        assert s3.objects(bucket, f"deploy/jobs/{job['id']}/") == uploaded
        image = httpx.get(f"{machines.api.url}/v1/jobs/{job['id']}/images/1", timeout=30)
        assert image.content == _frame_bytes(mic_upload, 1)
    finally:
        machines.stop()
