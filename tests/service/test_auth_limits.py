"""API keys (hashed, per-key isolation), exposure rule, and the limits, each with its 4xx."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from collections.abc import Iterator
from pathlib import Path

import pytest
from fastapi.testclient import TestClient

from sparsesplat.api.settings import Settings
from sparsesplat.server.app import create_app
from tests.service.test_bad_input import _cameras, _frame, _parts


def _client(tmp_path: Path, **settings: object) -> TestClient:
    values = {"data_dir": tmp_path / "data", "workers": 0, "render_workers": 0, **settings}
    return TestClient(create_app(Settings(**values)))  # type: ignore[arg-type]


def _cli(tmp_path: Path, *args: str) -> subprocess.CompletedProcess[str]:
    env = {**os.environ, "SPARSESPLAT_DATA_DIR": str(tmp_path / "data")}
    return subprocess.run([sys.executable, "-m", "sparsesplat.client.cli", *args],
                          env=env, capture_output=True, text=True, timeout=120)  # fmt: skip


@pytest.fixture
def keyed(tmp_path: Path) -> Iterator[tuple[TestClient, str, str]]:
    """A service with two keys created by the real ``sparsesplat keys create``."""
    keys = [json.loads(_cli(tmp_path, "keys", "--json", "create", name).stdout)["key"]
            for name in ("alice", "bob")]  # fmt: skip
    with _client(tmp_path) as client:
        yield client, keys[0], keys[1]


def test_keys_isolate_owners_and_unknown_keys_get_401(keyed: tuple[TestClient, str, str]) -> None:
    client, alice, bob = keyed
    assert client.get("/v1/jobs").status_code == 401
    assert client.get("/v1/jobs", headers={"Authorization": "Bearer nope"}).status_code == 401
    assert client.get("/healthz").status_code == 200  # liveness needs no key
    a = {"Authorization": f"Bearer {alice}"}
    b = {"Authorization": f"Bearer {bob}"}
    job = client.post("/v1/jobs", files=_parts(_cameras()), headers=a).json()
    assert client.get(f"/v1/jobs/{job['id']}", headers=a).status_code == 200
    # Another key's job does not exist for you: 404, never 403.
    assert client.get(f"/v1/jobs/{job['id']}", headers=b).status_code == 404
    assert client.delete(f"/v1/jobs/{job['id']}", headers=b).status_code == 404
    assert client.get("/v1/jobs", headers=b).json()["jobs"] == []


def test_a_revoked_key_stops_working(tmp_path: Path) -> None:
    created = json.loads(_cli(tmp_path, "keys", "--json", "create", "temp").stdout)
    with _client(tmp_path) as client:
        headers = {"Authorization": f"Bearer {created['key']}"}
        assert client.get("/v1/jobs", headers=headers).status_code == 200
        assert _cli(tmp_path, "keys", "revoke", created["id"]).returncode == 0
        import time

        time.sleep(0.1)
        assert client.get("/v1/jobs", headers=headers).status_code == 401
    listing = _cli(tmp_path, "keys", "list").stdout
    assert created["id"] in listing and "revoked" in listing and created["key"] not in listing


def test_serving_anonymously_off_loopback_is_refused(tmp_path: Path) -> None:
    result = _cli(tmp_path, "serve", "--host", "0.0.0.0", "--workers", "0")
    assert result.returncode == 2
    assert "without API keys" in result.stderr and "sparsesplat keys create" in result.stderr


def test_idempotency_key_returns_the_first_job(tmp_path: Path) -> None:
    with _client(tmp_path) as client:
        headers = {"Idempotency-Key": "upload-42"}
        first = client.post("/v1/jobs", files=_parts(_cameras()), headers=headers)
        again = client.post("/v1/jobs", files=_parts(_cameras()), headers=headers)
        assert (first.status_code, again.status_code) == (201, 200)
        assert first.json()["id"] == again.json()["id"]
        assert len(client.get("/v1/jobs").json()["jobs"]) == 1


def test_active_jobs_per_key_limit(tmp_path: Path) -> None:
    with _client(tmp_path, max_active_jobs_per_key=2) as client:
        for _ in range(2):
            assert client.post("/v1/jobs", files=_parts(_cameras())).status_code == 201
        refused = client.post("/v1/jobs", files=_parts(_cameras()))
        assert refused.status_code == 429 and "MAX_ACTIVE_JOBS_PER_KEY" in refused.json()["message"]


def test_render_rate_limit_answers_429_with_retry_after(tmp_path: Path) -> None:
    with _client(tmp_path, renders_per_second=1.0) as client:
        job = client.post("/v1/jobs", files=_parts(_cameras())).json()
        camera = {"convention": "opencv", "pose": "camera_to_world",
                  "matrix": _frame("x")["matrix"], "fx": 30, "fy": 30, "cx": 16, "cy": 16,
                  "width": 32, "height": 32}  # fmt: skip
        url = f"/v1/models/{job['id']}/render"
        statuses = [client.post(url, json={"camera": camera}).status_code for _ in range(3)]
        assert statuses[:2] == [409, 409]  # allowed through (the job has no model yet)
        limited = client.post(url, json={"camera": camera})
        assert limited.status_code == 429 and int(limited.headers["retry-after"]) >= 1


def test_render_size_and_request_size_limits(tmp_path: Path) -> None:
    with _client(tmp_path, max_upload_mb=1, max_render_megapixels=0.5) as client:
        job = client.post("/v1/jobs", files=_parts(_cameras())).json()
        big = client.post("/v1/jobs", files=[*_parts(_cameras()), ("x", ("x", b"0" * 2**21))])
        assert big.status_code == 413 and "MAX_UPLOAD_MB" in big.json()["message"]
        camera = {"convention": "opencv", "pose": "camera_to_world",
                  "matrix": _frame("x")["matrix"], "fx": 30, "fy": 30, "cx": 500, "cy": 500,
                  "width": 1000, "height": 1000}  # fmt: skip
        response = client.post(f"/v1/models/{job['id']}/render", json={"camera": camera})
        assert response.status_code == 413 and "downscale" in response.json()["message"]
        camera["width"] = camera["height"] = 600
        path = {"path": [camera] * 3, "downscale": 2}
        assert client.post(f"/v1/models/{job['id']}/render", json=path).status_code == 409
