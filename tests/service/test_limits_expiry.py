"""Per-key limits, usage, DELETE and model expiry on the real service: a key over a limit gets
a 4xx naming the limit and its usage, usage equals the bytes on disk, DELETE frees them at
once, and an unpinned model expires (404 ``expired``, its files gone) while a pinned one
stays."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import httpx
import numpy as np
import pytest
from PIL import Image

from tests.service.disk import files_bytes, renders, wait_for
from tests.service.live import FAST_SPEC, TERMINAL, LiveService, submit, upload_parts, wait_state
from tests.service.scenes import write_mic_upload

pytestmark = pytest.mark.shared_data

KEYS = ("ssk_test_alice", "ssk_test_bob")


def _auth(key: str) -> dict[str, str]:
    return {"Authorization": f"Bearer {key}"}


def _usage(url: str, key: str) -> dict:
    answer = httpx.get(url + "/v1/usage", headers=_auth(key), timeout=30)
    assert answer.status_code == 200, answer.text
    return dict(answer.json())


def _noisy_upload(folder: Path, size: int) -> Path:
    """The mic upload at ``size`` pixels with its images replaced by noise (PNG cannot
    compress it, so the upload is as large as its pixels)."""
    write_mic_upload(folder, size=size)
    rng = np.random.default_rng(0)
    for path in folder.glob("*.png"):
        Image.fromarray(rng.integers(0, 256, (size, size, 3), dtype=np.uint8)).save(path)
    return folder


def _on_disk(live: LiveService, job_ids: list[str]) -> int:
    return sum(files_bytes(live.data_dir / "jobs" / job_id) for job_id in job_ids)


def test_limits_name_the_limit_and_the_usage_and_delete_frees_at_once(
    tmp_path: Path, mic_upload: Path
) -> None:
    big = _noisy_upload(tmp_path / "big", size=400)  # 5 incompressible PNGs: ~2.4 MB
    live = LiveService(
        tmp_path / "data",
        {
            "SPARSESPLAT_API_KEYS": json.dumps(list(KEYS)),
            "SPARSESPLAT_MAX_JOBS_PER_KEY": "2",
            "SPARSESPLAT_MAX_STORED_MB_PER_KEY": "1",
        },
    )
    try:
        live.start_api(with_workers=False)
        alice, bob = KEYS
        first = submit(live.url, mic_upload, FAST_SPEC, **_auth(alice))
        usage = _usage(live.url, alice)
        assert usage["stored_bytes"] == _on_disk(live, [first["id"]]) > 0
        assert (usage["jobs"], usage["jobs_limit"], usage["active_jobs"]) == (1, 2, 1)
        assert usage["stored_limit_bytes"] == 1_000_000 and usage["model_ttl_days"] is None

        # Over the byte limit: 413 naming the usage and the limit; nothing stored.
        answer = httpx.post(live.url + "/v1/jobs", files=upload_parts(big, FAST_SPEC),
                            headers=_auth(alice), timeout=60)  # fmt: skip
        assert answer.status_code == 413, answer.text
        message = answer.json()["message"]
        owner = usage["owner"]
        stored_mb = f"{usage['stored_bytes'] / 1e6:.1f}"
        assert message.startswith(f"key {owner} stores {stored_mb} MB of its 1.0 MB limit")
        assert answer.json()["code"] == "storage_limit"
        assert _usage(live.url, alice)["stored_bytes"] == usage["stored_bytes"]

        # Over the job limit: 429 naming both figures.
        second = submit(live.url, mic_upload, FAST_SPEC, **_auth(alice))
        answer = httpx.post(live.url + "/v1/jobs", files=upload_parts(mic_upload, FAST_SPEC),
                            headers=_auth(alice), timeout=60)  # fmt: skip
        assert answer.status_code == 429, answer.text
        assert answer.json()["message"].startswith(f"key {owner} stores 2 jobs of its 2 limit")

        # Another key has its own figures.
        other = submit(live.url, mic_upload, FAST_SPEC, **_auth(bob))
        assert _usage(live.url, bob)["stored_bytes"] == _on_disk(live, [other["id"]])

        # DELETE frees the bytes at once, and the usage follows the disk.
        before = _usage(live.url, alice)["stored_bytes"]
        freed = _on_disk(live, [first["id"]])
        deleted = httpx.delete(f"{live.url}/v1/jobs/{first['id']}", headers=_auth(alice))
        assert deleted.status_code == 204
        assert not (live.data_dir / "jobs" / first["id"]).exists()
        after = _usage(live.url, alice)
        assert after["stored_bytes"] == before - freed == _on_disk(live, [second["id"]])
        assert after["jobs"] == 1

        # The CLI says the same.
        cli = subprocess.run(
            [sys.executable, "-m", "sparsesplat.client.cli", "usage", "--url", live.url,
             "--api-key", alice, "--json"],
            capture_output=True, text=True, timeout=60,
        )  # fmt: skip
        assert cli.returncode == 0, cli.stderr
        assert json.loads(cli.stdout) == after
    finally:
        live.stop()


def test_an_unpinned_model_expires_and_a_pinned_one_stays(tmp_path: Path, mic_upload: Path) -> None:
    ttl_s = 8.0
    live = LiveService(
        tmp_path / "data",
        {"SPARSESPLAT_MODEL_TTL_DAYS": repr(ttl_s / 86400), "SPARSESPLAT_SWEEP_INTERVAL_S": "1"},
    )
    try:
        live.start_api()
        live.wait_ready()
        kept = submit(live.url, mic_upload, FAST_SPEC)
        goes = submit(live.url, mic_upload, FAST_SPEC)
        assert wait_state(live.url, kept["id"], TERMINAL)["state"] == "succeeded"
        pinned = httpx.put(f"{live.url}/v1/models/{kept['id']}/pin", timeout=30)
        assert pinned.status_code == 200 and pinned.json()["pinned"], pinned.text
        assert pinned.json()["expires_at"] is None
        done = wait_state(live.url, goes["id"], TERMINAL)
        assert done["state"] == "succeeded" and done["expires_at"] is not None

        def expired() -> dict | None:
            answer = httpx.get(f"{live.url}/v1/models/{goes['id']}", timeout=30)
            return answer.json() if answer.status_code == 404 else None

        body = wait_for(expired, ttl_s + 30, "the unpinned model expires")
        assert body["code"] == "model_expired" and "expired" in body["message"]
        render = httpx.get(f"{live.url}/v1/models/{goes['id']}/export/ply", timeout=30)
        assert render.status_code == 404 and render.json()["code"] == "model_expired"
        assert not (live.data_dir / "jobs" / goes["id"]).exists(), "its bytes are freed"
        job = httpx.get(f"{live.url}/v1/jobs/{goes['id']}").json()
        assert job["expired"] and not job["has_model"] and job["state"] == "succeeded"

        # The pinned one, past the same age, still renders; usage equals the disk.
        renders(live.url, kept["id"])
        usage = httpx.get(live.url + "/v1/usage").json()
        assert (usage["models"], usage["pinned_models"]) == (1, 1)
        assert usage["stored_bytes"] == _on_disk(live, [kept["id"], goes["id"]])

        # Unpinned past its time, it expires too.
        assert httpx.delete(f"{live.url}/v1/models/{kept['id']}/pin").status_code in (200, 404)
        gone = httpx.get(f"{live.url}/v1/models/{kept['id']}", timeout=30)
        assert gone.status_code == 404 and gone.json()["code"] == "model_expired"

        # DELETE of a running job frees its bytes at once, and its worker, stopping, does
        # not write them back. (Until its next heartbeat tells it, the run may still write a
        # file or two of its own, which the worker removes as it stops; the upload, which only
        # the server writes, must be gone at once.)
        running = submit(live.url, mic_upload, {**FAST_SPEC, "iterations": 3000})
        folder = live.data_dir / "jobs" / running["id"]
        wait_for(lambda: (folder / "run" / "checkpoint.pt").exists(), 180, "it checkpoints")
        assert httpx.delete(f"{live.url}/v1/jobs/{running['id']}").status_code == 204
        assert not (folder / "upload").exists()
        later = submit(live.url, mic_upload, FAST_SPEC)
        assert wait_state(live.url, later["id"], TERMINAL)["state"] == "succeeded"
        assert not folder.exists(), "the stopped worker removed what it wrote after the delete"
        ids = [kept["id"], goes["id"], later["id"]]
        assert httpx.get(live.url + "/v1/usage").json()["stored_bytes"] == _on_disk(live, ids)
    finally:
        live.stop()
