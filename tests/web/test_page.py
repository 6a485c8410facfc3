"""The web page (issue #13) in headless Chromium against a real service on 127.0.0.1: the
pages and forms.

One smoke-scale job, submitted through the page's own form (the package fixture
``trained_job``), serves every test here and in test_viewer.py: the chart must gain points
while it trains (and survive a dropped WebSocket without gaps or duplicates), the job page's
held-out renders must equal ``POST /v1/models/{id}/render`` pixel for pixel, the jobs list can
cancel and delete, and no page may log a console error. Screenshots of each page land in
test-artifacts/web/ (git-ignored).
"""

from __future__ import annotations

import io
import json
import re
from pathlib import Path
from typing import Any

import httpx
import numpy as np
import pytest
from PIL import Image

from tests.service.live import LiveService, budget_spec, submit, wait_state
from tests.web.conftest import REPO, image_bytes, new_page
from tests.web.helpers import (
    PINHOLE_FIELDS,
    TrainedJob,
    pixels,
    post_render,
    wire_cameras,
)

pytestmark = pytest.mark.timeout(900)


def test_page_and_assets_are_served_by_the_server(service: LiveService) -> None:
    """``/`` is the page; every importmap entry is a vendored file served as JavaScript; no
    asset comes from elsewhere; each vendored package carries its licence."""
    index = httpx.get(service.url + "/", timeout=10)
    assert index.status_code == 200
    assert index.headers["content-type"].startswith("text/html")
    html = index.text
    assert "http://" not in html and "https://" not in html, "the page must not use a CDN"
    found = re.search(r'<script type="importmap">(.*?)</script>', html, re.S)
    assert found is not None, "no importmap in the page"
    importmap = json.loads(found[1])
    for name, target in importmap["imports"].items():
        assert target.startswith("/static/vendor/"), name
        if target.endswith("/"):
            continue
        answer = httpx.get(service.url + target, timeout=30)
        assert answer.status_code == 200, target
        assert answer.headers["content-type"].startswith("text/javascript"), target
    static = REPO / "server" / "static"
    for package in ("three", "spark", "uplot"):
        assert (static / "vendor" / package / "LICENSE").is_file(), package
    for module in (static / "js").glob("*.js"):
        for spec in re.findall(r'from\s+"([^"]+)"|import\("([^"]+)"\)', module.read_text()):
            target = spec[0] or spec[1]
            assert (
                target.startswith("./")
                or target in importmap["imports"]
                or any(target.startswith(k) for k in importmap["imports"] if k.endswith("/"))
            ), f"{module.name} imports {target}"
    for bad in ("/static/../app.py", "/static/%2e%2e/routes/pages.py", "/static/nope.js"):
        assert httpx.get(service.url + bad, timeout=10).status_code == 404, bad


@pytest.mark.shared_data
def test_form_submits_a_job_and_the_chart_fills_in_while_it_trains(
    trained_job: TrainedJob, service: LiveService
) -> None:
    """The form's job trained; the chart gained points while the job ran; after a dropped
    connection the page resumed with ?after= and holds every record exactly once."""
    assert trained_job.state == "succeeded", trained_job.seen[-5:]
    running_points = sorted({p for s, p in trained_job.seen if s == "running" and p > 0})
    assert len(running_points) >= 2, f"the chart did not grow while training: {trained_job.seen}"
    records = httpx.get(f"{service.url}/v1/jobs/{trained_job.id}/metrics", timeout=10).json()
    assert trained_job.chart_points == len(records) >= 2
    assert trained_job.connections >= 2, "the dropped WebSocket was not reopened"
    assert trained_job.api_key_in_session is None, "no key is needed on a loopback server"
    assert trained_job.photos == 5, "the uploading tab shows each photo beside its render"
    assert not trained_job.console_errors, trained_job.console_errors


@pytest.mark.shared_data
def test_jobs_list_shows_state_progress_and_metrics(
    browser: Any, service: LiveService, trained_job: TrainedJob
) -> None:
    context, page, console = new_page(browser, service.url)
    page.goto("/")
    row = page.locator(f"#jobs-body tr[data-job-id='{trained_job.id}']")
    row.wait_for()
    assert row.get_attribute("data-state") == "succeeded"
    cells = row.locator("td").all_text_contents()
    job = httpx.get(f"{service.url}/v1/jobs/{trained_job.id}", timeout=10).json()
    # A time-budget job has no planned total: the cell gives the iterations it did.
    assert f"{job['progress']['iteration']} iterations" in cells[2], cells
    assert job["progress"]["iteration"] > 0
    assert cells[3].endswith("dB") and re.match(r"^0\.\d{3}$", cells[4]), cells
    console.assert_clean()
    context.close()


@pytest.mark.shared_data
def test_job_page_heldout_renders_equal_the_render_api(
    browser: Any, service: LiveService, trained_job: TrainedJob
) -> None:
    """Each held-out view's render on the job page is, pixel for pixel, what
    ``POST /v1/models/{id}/render`` returns for that camera."""
    cameras = wire_cameras(service.url, trained_job.id)
    context, page, console = new_page(browser, service.url)
    page.goto(f"/#/jobs/{trained_job.id}")
    test_indices = [i for i, c in enumerate(cameras) if c["split"] == "test"]
    assert len(test_indices) == 2
    for index in test_indices:
        selector = f"#heldout-views img.render[data-camera-index='{index}'][data-ready='1']"
        page.wait_for_selector(selector)
        shown = image_bytes(page, selector)
        camera = {k: cameras[index][k] for k in PINHOLE_FIELDS}
        expected = post_render(service.url, trained_job.id, camera)
        assert np.array_equal(pixels(shown), pixels(expected)), f"camera {index}"
    page.wait_for_selector("#training-views img.render[data-ready='1']")
    console.assert_clean()
    context.close()


@pytest.mark.shared_data
def test_job_page_shows_the_uploaded_photos_and_priors_from_the_api(
    browser: Any, service: LiveService, trained_job: TrainedJob
) -> None:
    """A tab that did not upload the job still shows each photo (``/images/{i}``) beside its
    render, byte for byte the upload, and a depth prior (or a note) beside each training
    view; no sentence claims the API does not serve them."""
    cameras = wire_cameras(service.url, trained_job.id)
    context, page, console = new_page(browser, service.url)
    page.goto(f"/#/jobs/{trained_job.id}")
    page.wait_for_function(
        "() => [...document.querySelectorAll('img.photo')].filter((i) => i.complete"
        " && i.naturalWidth > 0).length === 5"
    )
    for index in range(len(cameras)):
        selector = f"figure[data-camera-index='{index}'] img.photo"
        shown = image_bytes(page, selector)
        uploaded = httpx.get(f"{service.url}/v1/jobs/{trained_job.id}/images/{index}", timeout=30)
        assert np.array_equal(pixels(shown), pixels(uploaded.content)), f"photo {index}"
    training = page.locator("#training-views figure")
    assert training.count() == 3
    priors = page.locator("#training-views img.prior")
    notes = page.locator("#training-views .pair span.muted", has_text="no depth prior")
    page.wait_for_function(
        "() => [...document.querySelectorAll('#training-views img.prior')].every("
        "(i) => i.complete && i.naturalWidth > 0)"
    )
    assert priors.count() + notes.count() == 3
    text = page.text_content("#job-views") or ""
    assert "does not serve" not in text and "no API route" not in text
    console.assert_clean()
    context.close()


@pytest.mark.shared_data
def test_cancel_and_delete_from_the_jobs_list(
    browser: Any, service: LiveService, mic_folder: Path, trained_job: TrainedJob
) -> None:
    # A budget longer than the wait for the cancel below, so that only the click ends the job:
    # 2000 iterations took about 10 s here, and a fast machine could finish them before the
    # page loaded and the button was clicked (a cancel leaves a finished job as it is).
    job = submit(service.url, mic_folder, budget_spec(600.0))
    context, page, console = new_page(browser, service.url)
    page.goto("/")
    row = page.locator(f"#jobs-body tr[data-job-id='{job['id']}']")
    row.locator("button", has_text="Cancel").click()
    wait_state(service.url, job["id"], {"cancelled"}, timeout=120)
    page.locator(f"#jobs-body tr[data-job-id='{job['id']}'][data-state='cancelled']").wait_for()
    row.locator("button", has_text="Delete").click()  # confirm() is accepted
    row.wait_for(state="detached")
    assert httpx.get(f"{service.url}/v1/jobs/{job['id']}", timeout=10).status_code == 404
    console.assert_clean()
    context.close()


def test_api_key_entered_once_and_kept_in_the_tab(
    browser: Any, tmp_path: Path, artifacts: Path
) -> None:
    """A server with keys: the page asks once, keeps the key in session storage (a reload does
    not ask again, another tab does), sends it on requests and on the WebSocket."""
    key = "web-test-key-0123456789"
    live = LiveService(tmp_path / "data", env={"SPARSESPLAT_API_KEYS": json.dumps([key])})
    live.start_api(with_workers=False)
    try:
        context, page, console = new_page(browser, live.url)
        page.goto("/")
        page.wait_for_selector("#key-dialog[open]")
        page.fill("#key-input", key)
        page.click("#key-dialog button[value='save']")
        page.wait_for_selector("#jobs-empty:not([hidden])")
        assert page.evaluate("() => sessionStorage.getItem('sparsesplat.apiKey')") == key
        page.reload()
        page.wait_for_selector("#jobs-empty:not([hidden])")
        assert not page.is_visible("#key-dialog")
        # The status line shows the key's stored bytes (GET /v1/usage, sent with the key).
        page.wait_for_function(
            "() => document.getElementById('server-status').textContent.includes('stored 0.0 MB')"
        )
        # The first request went out without a key: its 401 is the only console error allowed.
        console.assert_clean(allowed=("401",))
        assert sum("401" in e for e in console.errors) == 1
        job = httpx.post(
            live.url + "/v1/jobs",
            headers={"Authorization": f"Bearer {key}"},
            files=_tiny_upload(),
            timeout=30,
        )
        assert job.status_code == 201, job.text
        page.goto(f"/#/jobs/{job.json()['id']}")
        page.wait_for_function(
            "() => document.querySelector('#job-live')?.dataset.status === 'live'"
        )
        page.screenshot(path=str(artifacts / "job-queued-with-api-key.png"))
        context.close()
        other, other_page, _ = new_page(browser, live.url)
        other_page.goto("/")
        other_page.wait_for_selector("#key-dialog[open]")
        other.close()
    finally:
        live.stop()


def _tiny_upload() -> list[tuple[str, Any]]:
    """A valid two-view upload of 16x16 images (the job only has to exist)."""
    parts: list[tuple[str, Any]] = []
    frames = []
    for i in range(2):
        buffer = io.BytesIO()
        Image.new("RGB", (16, 16), (40 * i, 90, 160)).save(buffer, format="PNG")
        parts.append(("images", (f"v{i}.png", buffer.getvalue(), "image/png")))
        frames.append(
            {
                "image": f"v{i}.png", "fx": 20.0, "fy": 20.0, "cx": 8.0, "cy": 8.0,
                "matrix": [[1, 0, 0, 0.2 * i], [0, 1, 0, 0], [0, 0, 1, 3], [0, 0, 0, 1]],
            }
        )  # fmt: skip
    cameras = {"convention": "opencv", "pose": "camera_to_world", "frames": frames}
    parts.append(("cameras", ("cameras.json", json.dumps(cameras).encode(), "application/json")))
    return parts


@pytest.mark.shared_data
def test_screenshots_of_each_page(
    browser: Any, service: LiveService, trained_job: TrainedJob, artifacts: Path
) -> None:
    """jobs.png, job.png and viewer.png in test-artifacts/web/ (looked at by a person)."""
    context, page, console = new_page(browser, service.url)
    page.goto("/")
    page.locator(f"#jobs-body tr[data-job-id='{trained_job.id}']").wait_for()
    page.screenshot(path=str(artifacts / "jobs.png"), full_page=True)
    page.goto(f"/#/jobs/{trained_job.id}")
    page.wait_for_selector("#heldout-views img.render[data-ready='1']")
    page.wait_for_function(
        "() => { const r = [...document.querySelectorAll('img.render')];"
        " return r.length === 5 && r.every((i) => i.dataset.ready === '1'); }"
    )
    page.screenshot(path=str(artifacts / "job.png"), full_page=True)
    page.goto(f"/#/jobs/{trained_job.id}/viewer")
    page.wait_for_selector("#viewer-canvas[data-ready='1']")
    page.click("#viewer-cameras button[data-split='test']")
    page.click("#viewer-render")
    page.wait_for_selector("#compare-server")
    page.screenshot(path=str(artifacts / "viewer.png"), full_page=True)
    for name in ("jobs.png", "job.png", "viewer.png"):
        assert (artifacts / name).stat().st_size > 10_000, name
    console.assert_clean()
    context.close()
