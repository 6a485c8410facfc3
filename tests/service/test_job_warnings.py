"""What only training can find becomes a warning on the job (issue #28): against a real
``sparsesplat serve``, an upload whose held-out poses are read the wrong way passes every
upload check, trains, and ends succeeded with a warning in the job record, in its event stream,
in the SDK (``JobWarning``) and in ``sparsesplat status``; the same upload with its poses
right ends without that warning."""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

from sparsesplat.client import Client
from sparsesplat.client.errors import JobWarning
from tests.service.live import FAST_SPEC, TERMINAL, LiveService, job_events, submit, wait_state
from tests.service.scenes import turn_held_out_cameras_around

pytestmark = pytest.mark.shared_data

EMPTY = "2 of 2 evaluated views render (nearly) empty"
"""What the warning says when both held-out views see nothing."""


def test_held_out_poses_read_the_wrong_way_end_with_a_job_warning(
    live: LiveService, mic_upload: Path, tmp_path: Path
) -> None:
    turned = turn_held_out_cameras_around(shutil.copytree(mic_upload, tmp_path / "turned"))
    live.start_api()
    live.wait_ready()
    wrong = submit(live.url, turned, FAST_SPEC)  # 201: the upload checks cannot see it
    right = submit(live.url, mic_upload, FAST_SPEC)
    done = wait_state(live.url, wrong["id"], TERMINAL, timeout=300)
    control = wait_state(live.url, right["id"], TERMINAL, timeout=300)
    assert done["state"] == "succeeded" and control["state"] == "succeeded", live.tail()

    # GET /v1/jobs/{id} (what wait_state read) carries it.
    (warning,) = [w for w in done["warnings"] if EMPTY in w]
    assert "check the poses (convention, pose)" in warning
    assert str(live.data_dir) not in warning and "/jobs/" not in warning
    assert not any(EMPTY in w for w in control["warnings"]), control["warnings"]

    # The same words as a 'warning' event, once, before the job's terminal state.
    events = job_events(live.url, wrong["id"])
    warned = [e for e in events if e["type"] == "warning"]
    assert [e["data"]["message"] for e in warned] == done["warnings"]
    assert warned[-1]["seq"] < events[-1]["seq"] and events[-1]["data"]["state"] == "succeeded"

    # The SDK's wait() and the CLI's status show it.
    with Client(live.url) as client, pytest.warns(JobWarning, match=r"render \(nearly\) empty"):
        client.job(wrong["id"]).wait(progress=False)
    status = subprocess.run(
        [sys.executable, "-m", "sparsesplat", "status", wrong["id"]],
        env={**os.environ, "SPARSESPLAT_URL": live.url}, capture_output=True, text=True,
        timeout=120,
    )  # fmt: skip
    assert status.returncode == 0 and EMPTY in status.stdout, status.stdout + status.stderr
