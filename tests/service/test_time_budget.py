"""A time budget is a deadline: the job trains until the budget is spent (its schedule
following the elapsed fraction) and reports the budget against the seconds it used."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import httpx
import pytest

from tests.service.live import FAST_SPEC, LiveService, submit, wait_state

pytestmark = pytest.mark.shared_data


def _trained(live: LiveService, upload: Path, spec: dict[str, Any]) -> tuple[dict, dict]:
    """Start the service and train ``spec`` on ``upload`` to its end (asserting success):
    the finished job and its model."""
    live.start_api()
    live.wait_ready()
    job = submit(live.url, upload, spec)
    done = wait_state(live.url, job["id"], {"succeeded", "failed", "cancelled"}, timeout=300)
    assert done["state"] == "succeeded", live.tail()
    return done, httpx.get(f"{live.url}/v1/models/{job['id']}").json()


def test_a_time_budget_trains_until_it_is_spent_and_reports_it(
    live: LiveService, mic_upload
) -> None:
    spec = {k: v for k, v in FAST_SPEC.items() if k != "iterations"} | {"time_budget_s": 6.0}
    done, model = _trained(live, mic_upload, spec)
    metrics = model["metrics"]
    # Trained until the budget was spent: at least 6 s, at most one iteration more (the
    # engine tests pin the exact rule with a fake clock; one iteration here is well under 2 s).
    assert metrics["time_budget_s"] == 6.0
    assert 6.0 <= metrics["seconds"] < 8.0, metrics
    assert model["iterations"] >= 1
    # Under a deadline the progress has no iteration total; the last beat shows the end.
    assert done["progress"]["total"] is None
    assert done["progress"]["iteration"] == model["iterations"]


def test_a_default_length_job_stops_at_its_time_limit_and_says_so(
    live: LiveService, mic_upload
) -> None:
    # No iterations and no budget: the preset's default length (6000 for mic) with its time
    # limit, here lowered to 3 s so that it binds long before the length.
    spec = {k: v for k, v in FAST_SPEC.items() if k != "iterations"}
    spec |= {"overrides": {"time_limit_s": 3.0}}
    done, model = _trained(live, mic_upload, spec)
    metrics = model["metrics"]
    assert metrics["time_limit_s"] == 3.0
    assert 3.0 <= metrics["seconds"] < 5.0, metrics
    assert 1 <= model["iterations"] < 6000
    (warning,) = [w for w in done["warnings"] if "time limit" in w]
    assert f"after {model['iterations']} of 6000 iterations" in warning
