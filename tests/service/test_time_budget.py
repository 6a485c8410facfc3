"""A time budget instead of an iteration count: the schedule is compressed to fit, from the
iteration cost measured on the scene at the start of the run."""

from __future__ import annotations

import json

import httpx
import pytest

from tests.service.live import FAST_SPEC, LiveService, submit, wait_state

pytestmark = pytest.mark.shared_data


def test_time_budget_sets_the_iteration_count_from_a_timed_probe(
    live: LiveService, mic_upload
) -> None:
    live.start_api()
    live.wait_ready()
    spec = {k: v for k, v in FAST_SPEC.items() if k != "iterations"} | {"time_budget_s": 6.0}
    job = submit(live.url, mic_upload, spec)
    done = wait_state(live.url, job["id"], {"succeeded", "failed", "cancelled"}, timeout=300)
    assert done["state"] == "succeeded", live.tail()
    budget = json.loads((live.data_dir / "jobs" / job["id"] / "run" / "budget.json").read_text())
    model = httpx.get(f"{live.url}/v1/models/{job['id']}").json()
    # The run trained exactly the iterations the probe fitted into the budget (>= 1), and the
    # progress it reported counted towards that total.
    assert model["iterations"] == budget["iterations"] >= 1
    assert done["progress"]["total"] == budget["iterations"]
    # The last beat ran after training: a finished job shows its final iteration.
    assert done["progress"]["iteration"] == budget["iterations"]
