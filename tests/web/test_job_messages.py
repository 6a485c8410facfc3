"""A job's warnings and a long error on the page, in headless Chromium against a real service
(issue #28: a failed job's long error overflowed the jobs table): the job page shows every
warning and the whole error, each wraps inside its card over several lines, and no page is
wider than the window, at a desktop width and at a phone's.

The warned job's held-out poses are read the wrong way (tests/service/test_job_warnings.py has
the same case against the API); the failed job is three copies of one photo under long file
names, which camera estimation refuses naming them (a long message with long unbroken words).
"""

from __future__ import annotations

import json
import shutil
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import httpx
import pytest

from tests.service.live import FAST_SPEC, TERMINAL, LiveService, submit, wait_state
from tests.service.scenes import turn_held_out_cameras_around
from tests.web.conftest import new_page

pytestmark = [pytest.mark.timeout(900), pytest.mark.shared_data]

WIDTHS = (1280, 400)
"""Window widths the page is checked at: a desktop and a narrow phone."""
LONG_NAMES = [f"IMG_20240612_{'0123456789' * 16}_copy{i}.png" for i in range(3)]
"""File names of 189 characters without a space: words no line break can fall inside."""

_BOX = """(selector) => {
    const box = document.querySelector(selector);
    const card = box.closest('.card, td');
    const r = box.getBoundingClientRect(), c = card.getBoundingClientRect();
    return {
        visible: r.width > 0 && r.height > 0,
        scrollWidth: box.scrollWidth, clientWidth: box.clientWidth,
        left: r.left, right: r.right, height: r.height,
        cardLeft: c.left, cardRight: c.right,
        fontSize: parseFloat(getComputedStyle(box).fontSize),
        pageWidth: document.documentElement.scrollWidth, window: window.innerWidth,
    };
}"""
"""Where a box lies against its card (or table cell) and the window."""


@pytest.fixture(scope="module")
def jobs(service: LiveService, mic_folder: Path, tmp_path_factory: pytest.TempPathFactory) -> Any:
    """(a succeeded job with a warning, a failed job with a long error), both ended."""
    pytest.importorskip("pycolmap")
    from tests.engine.sfm.textured import camera_poses, write_photos

    folder = tmp_path_factory.mktemp("turned") / "upload"
    turned = turn_held_out_cameras_around(shutil.copytree(mic_folder, folder))
    warned = submit(service.url, turned, FAST_SPEC)
    (photo,) = write_photos(tmp_path_factory.mktemp("photos"), camera_poses(1))
    parts: list[tuple[str, Any]] = [("spec", (None, json.dumps(FAST_SPEC)))]
    parts += [("images", (name, photo.read_bytes(), "image/png")) for name in LONG_NAMES]
    answer = httpx.post(f"{service.url}/v1/jobs", files=parts, timeout=60)
    assert answer.status_code == 201, answer.text
    warned = wait_state(service.url, warned["id"], TERMINAL, timeout=600)
    failed = wait_state(service.url, answer.json()["id"], TERMINAL, timeout=600)
    assert warned["state"] == "succeeded" and warned["warnings"], warned
    assert failed["state"] == "failed" and LONG_NAMES[0] in failed["error"], failed
    assert len(failed["error"]) > 400
    return warned, failed


def _assert_wraps_inside(box: dict[str, Any], what: str) -> None:
    """The box is shown, nothing in it is wider than it, it lies inside its card, it wrapped
    onto several lines, and the page is no wider than the window."""
    assert box["visible"], what
    assert box["scrollWidth"] <= box["clientWidth"], f"{what} overflows its box: {box}"
    assert box["cardLeft"] <= box["left"] and box["right"] <= box["cardRight"] + 0.5, (what, box)
    assert box["height"] >= 1.8 * box["fontSize"], f"{what} is on one line: {box}"
    assert box["pageWidth"] <= box["window"], f"the page is wider than the window: {box}"


@pytest.fixture(params=WIDTHS)
def width(request: pytest.FixtureRequest) -> int:
    """Each window width the pages are checked at."""
    return int(request.param)


@pytest.fixture
def job_page(browser: Any, service: LiveService, width: int) -> Iterator[Callable[[str, str], Any]]:
    """``job_page(job_id, selector)`` opens a job's page in a new ``width`` x 800 window and
    returns the page once ``selector`` shows on it; after the test the console must have
    stayed clean, and the window is closed."""
    context, page, console = new_page(
        browser, service.url, viewport={"width": width, "height": 800}
    )

    def open_job(job_id: str, selector: str) -> Any:
        page.goto(f"/#/jobs/{job_id}")
        page.wait_for_selector(selector)
        return page

    try:
        yield open_job
        console.assert_clean()
    finally:
        context.close()


def test_job_page_shows_the_warnings_wrapped_inside_the_page(
    job_page: Callable[[str, str], Any], jobs: Any, width: int, artifacts: Path
) -> None:
    warned, _ = jobs
    page = job_page(warned["id"], "#job-warnings:not([hidden]) p.warning-text")
    shown = page.locator("#job-warnings p.warning-text").all_text_contents()
    assert shown == [f"Warning: {w}" for w in warned["warnings"]]
    assert not page.is_visible("#job-error")
    _assert_wraps_inside(page.evaluate(_BOX, "#job-warnings p.warning-text"), "the warning")
    page.screenshot(path=str(artifacts / f"job-warning-{width}.png"), full_page=True)


def test_a_long_error_wraps_on_the_job_page_and_in_the_jobs_list(
    job_page: Callable[[str, str], Any], jobs: Any, width: int, artifacts: Path
) -> None:
    _, failed = jobs
    page = job_page(failed["id"], "#job-error:not([hidden])")
    assert page.text_content("#job-error") == failed["error"]
    _assert_wraps_inside(page.evaluate(_BOX, "#job-error"), "the job page's error")
    page.screenshot(path=str(artifacts / f"job-error-{width}.png"), full_page=True)

    page.goto("/")
    row = f"#jobs-body tr[data-job-id='{failed['id']}']"
    page.wait_for_selector(f"{row} .error-text")
    # The list shows the first lines; the cell's title holds all of it.
    assert page.get_attribute(f"{row} td[title]", "title") == failed["error"]
    _assert_wraps_inside(page.evaluate(_BOX, f"{row} .error-text"), "the jobs list's error")
    page.screenshot(path=str(artifacts / f"jobs-error-{width}.png"), full_page=True)


@pytest.fixture(scope="module")
def photos_job(service: LiveService, tmp_path_factory: pytest.TempPathFactory) -> Any:
    """A photos-only job of three photos of one scene and a fourth of another, ended: the
    fourth is left out by name and the job trains on the three."""
    pytest.importorskip("pycolmap")
    from tests.engine.sfm.textured import camera_poses, write_photos

    folder = tmp_path_factory.mktemp("photos")
    paths = write_photos(folder, camera_poses(3))
    paths += write_photos(folder, camera_poses(1), seed=2, prefix="stray")
    spec = {"iterations": 50, "depth_prior": "none", "color_model": "sh", "init": "sparse"}
    parts: list[tuple[str, Any]] = [("spec", (None, json.dumps(spec)))]
    parts += [("images", (p.name, p.read_bytes(), "image/png")) for p in paths]
    answer = httpx.post(f"{service.url}/v1/jobs", files=parts, timeout=60)
    assert answer.status_code == 201, answer.text
    job = wait_state(service.url, answer.json()["id"], TERMINAL, timeout=600)
    assert job["state"] == "succeeded" and job["warnings"], job
    return job


def test_job_page_lists_each_photo_placed_or_left_out(
    job_page: Callable[[str, str], Any], photos_job: Any, width: int, artifacts: Path
) -> None:
    page = job_page(photos_job["id"], "#job-details dt")
    terms = page.locator("#job-details dt").all_text_contents()
    values = page.locator("#job-details dd").all_text_contents()
    shown = dict(zip(terms, values, strict=True))
    photos = photos_job["progress"]["cameras"]["photos"]
    assert [p["name"] for p in photos] == [
        "photo_0.png",
        "photo_1.png",
        "photo_2.png",
        "stray_0.png",
    ]
    for p in photos[:3]:
        assert shown[p["name"]].startswith(
            f"placed: {p['matches']:,} matches, {p['points']:,} points"
        )
        assert f"{p['error_px']:.2f} px error" in shown[p["name"]]
    stray = photos[3]
    assert shown["stray_0.png"] == f"left out ({stray['matches']:,} matches): {stray['reason']}"
    # Four photos were uploaded; the views line counts the three trained on.
    assert shown["Views"] == "3 training (1 of 4 photos left out, see below), 0 held-out"
    assert page.evaluate("document.documentElement.scrollWidth") <= width
    page.screenshot(path=str(artifacts / f"job-photos-{width}.png"), full_page=True)
