"""Issue #57's experiment as a test: the service's data folder on a 45 MB filesystem.

Mic jobs submitted there (three of the issue's, 60 iterations with the neural colour,
and one whose disk is filled under it mid-training so that a write really fails with ENOSPC)
all end in a terminal state with the cause in their error; no partial file remains; a model
trained earlier still renders; once space is freed a new job succeeds.

The filesystem is a 45 MB tmpfs mounted for the test: that needs root (CI runs as root); the
test is skipped, saying why, where mounting is not permitted.
"""

from __future__ import annotations

import os
import shutil
import subprocess
from collections.abc import Iterator
from pathlib import Path

import httpx
import pytest

from tests.service.disk import partial_files, renders, wait_for
from tests.service.live import FAST_SPEC, TERMINAL, LiveService, submit, wait_state

pytestmark = pytest.mark.shared_data

SIZE_MB = 45
NO_SPACE = "no space left on device"


@pytest.fixture
def small_disk(tmp_path: Path) -> Iterator[Path]:
    """A 45 MB tmpfs mounted at ``tmp_path / "disk"`` (skips where mounting is refused)."""
    mount = tmp_path / "disk"
    mount.mkdir()
    if os.geteuid() != 0:
        pytest.skip("mounting a 45 MB tmpfs needs root (CI runs as root)")
    done = subprocess.run(
        ["mount", "-t", "tmpfs", "-o", f"size={SIZE_MB}m", "tmpfs", str(mount)],
        capture_output=True, text=True, check=False,
    )  # fmt: skip
    if done.returncode != 0:
        pytest.skip(f"cannot mount a tmpfs here: {done.stderr.strip() or done.returncode}")
    try:
        yield mount
    finally:
        subprocess.run(["umount", "-l", str(mount)], check=False)


def _fill(folder: Path, leave: int) -> Path:
    """A file taking all but ``leave`` bytes of ``folder``'s filesystem."""
    filler = folder / "filler.bin"
    size = max(shutil.disk_usage(folder).free - leave, 0)
    with filler.open("wb") as f:
        chunk = b"\0" * 2**20
        while size > 0:
            f.write(chunk[: min(size, len(chunk))])
            size -= len(chunk)
    return filler


def test_45_mb_data_folder(small_disk: Path, mic_upload: Path) -> None:
    live = LiveService(
        small_disk,  # the data folder is the small filesystem; the log stays beside it
        {"SPARSESPLAT_DISK_RESERVE_MB": "2", "SPARSESPLAT_DISK_WAIT_S": "5"},
    )
    report: list[str] = []
    try:
        live.start_api()
        live.wait_ready()
        earlier = submit(live.url, mic_upload, FAST_SPEC)
        assert wait_state(live.url, earlier["id"], TERMINAL)["state"] == "succeeded", live.tail()
        stored = httpx.get(f"{live.url}/v1/jobs/{earlier['id']}").json()["disk_bytes"]
        report.append(f"earlier model {earlier['id']}: {stored} bytes")

        # The issue's three jobs: 60 iterations with the neural colour each (its 150 MB hash
        # table and Adam state are what cannot fit).
        issue_spec = {"iterations": 60, "depth_prior": "none", "color_model": "neural"}
        issue_jobs = [submit(live.url, mic_upload, issue_spec) for _ in range(3)]
        # One more that fits when it starts; then the disk fills under it while it trains.
        filled = submit(
            live.url, mic_upload,
            {**FAST_SPEC, "iterations": 3000, "overrides": {"densify.max_gaussians": 12000}},
        )  # fmt: skip
        wait_for(lambda: (live.data_dir / "jobs" / filled["id"] / "run" / "checkpoint.pt").exists(),
                 300, "the last job wrote a checkpoint")  # fmt: skip
        filler = _fill(small_disk, leave=200_000)
        report.append(f"healthz once filled: {httpx.get(live.url + '/healthz').json()}")

        jobs = [wait_state(live.url, j["id"], TERMINAL, timeout=300) for j in (*issue_jobs, filled)]
        for job in jobs:
            report.append(f"{job['id']}: {job['state']}: {job['error']}")
            assert job["state"] == "failed" and job["error"].startswith(NO_SPACE), job
        assert all("to start this job (needs ~" in j["error"] for j in jobs[:3])
        assert partial_files(small_disk) == [], "no partial file remains"
        run = live.data_dir / "jobs" / filled["id"] / "run"
        assert not (run / "checkpoint.pt").exists(), "the failed job's checkpoint is freed"
        renders(live.url, earlier["id"])

        # Space freed: a new job succeeds.
        filler.unlink()
        after = submit(live.url, mic_upload, FAST_SPEC)
        assert wait_state(live.url, after["id"], TERMINAL)["state"] == "succeeded", live.tail()
        report.append(f"after freeing: {after['id']} succeeded")
        report.append(f"healthz: {httpx.get(live.url + '/healthz').json()}")
    finally:
        print("\n".join(report))
        live.stop()
