"""Fixtures for the web page tests: headless Chromium (Debian's package) driven by Playwright
against a real ``sparsesplat serve`` on 127.0.0.1.

WebGL in headless Chromium runs on SwiftShader, its software renderer. The flags are explicit
(:data:`CHROMIUM_FLAGS`): ``--use-gl=angle --use-angle=swiftshader`` picks ANGLE on SwiftShader
and ``--enable-unsafe-swiftshader`` opts in to it (Chromium 13x+ deprecates falling back to it
silently; Playwright also passes that one by default).
"""

from __future__ import annotations

import base64
import os
import re
import shutil
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest

from tests.service.live import LiveService
from tests.service.scenes import MIC, write_mic_upload
from tests.web.helpers import FORM_BUDGET_S, TERMINAL, TrainedJob

REPO = Path(__file__).resolve().parents[2]
ARTIFACTS = REPO / "test-artifacts" / "web"
"""Screenshots and logs of the run (git-ignored)."""
CHROMIUM_FLAGS = ["--use-gl=angle", "--use-angle=swiftshader", "--enable-unsafe-swiftshader"]
"""Software WebGL 2 (SwiftShader through ANGLE) in headless Chromium."""
VIEWPORT = {"width": 1280, "height": 900}


def chromium_executable() -> str | None:
    """Debian's chromium (or ``SPARSESPLAT_CHROMIUM``); None when not installed."""
    explicit = os.environ.get("SPARSESPLAT_CHROMIUM")
    if explicit:
        return explicit if Path(explicit).is_file() else None
    for name in ("chromium", "chromium-browser"):
        found = shutil.which(name)
        if found:
            return found
    return None


@pytest.fixture(scope="session")
def artifacts() -> Path:
    """Folder for screenshots (test-artifacts/web, git-ignored)."""
    ARTIFACTS.mkdir(parents=True, exist_ok=True)
    return ARTIFACTS


@pytest.fixture(scope="session")
def browser() -> Iterator[Any]:
    """Headless Chromium with software WebGL; skips when Chromium or Playwright is missing."""
    executable = chromium_executable()
    if executable is None:
        pytest.skip(
            "Debian's chromium is not installed (apt-get install chromium; .ci/run installs it)"
        )
    try:
        from playwright.sync_api import sync_playwright
    except ImportError:
        pytest.skip("playwright is not installed (pip install -e '.[dev]')")
    with sync_playwright() as p:
        browser = p.chromium.launch(executable_path=executable, args=CHROMIUM_FLAGS)
        yield browser
        browser.close()


class Console:
    """Console errors and uncaught exceptions of a page (acceptance: none)."""

    def __init__(self, page: Any) -> None:
        self.errors: list[str] = []
        self.messages: list[str] = []
        page.on("console", self._on_console)
        page.on("pageerror", lambda exc: self.errors.append(f"uncaught: {exc}"))

    def _on_console(self, message: Any) -> None:
        self.messages.append(f"{message.type}: {message.text}")
        if message.type == "error":
            self.errors.append(message.text)

    def assert_clean(self, allowed: tuple[str, ...] = ()) -> None:
        """No console error except those containing one of ``allowed``."""
        errors = [e for e in self.errors if not any(a in e for a in allowed)]
        assert not errors, "console errors:\n" + "\n".join(errors)


SMALL_VIEWPORT = {"width": 1280, "height": 480}
"""A short window: the viewer's canvas fits it at 320x320. A smoke-scale model (a few dozen
iterations) is a fog of large Gaussians, costly per pixel for SwiftShader and for the server's
CPU rasterizer alike, so the viewer tests keep the canvas small."""


def new_page(
    browser: Any, base_url: str, api_key: str | None = None, viewport: dict[str, int] = VIEWPORT
) -> tuple[Any, Any, Console]:
    """(context, page, console) with ``api_key`` already in the tab's session storage."""
    context = browser.new_context(viewport=viewport, base_url=base_url)
    if api_key:
        context.add_init_script(f"sessionStorage.setItem('sparsesplat.apiKey', {api_key!r});")
    page = context.new_page()
    page.set_default_timeout(60_000)
    page.on("dialog", lambda dialog: dialog.accept())  # window.confirm before a delete
    return context, page, Console(page)


def image_bytes(page: Any, selector: str) -> bytes:
    """The bytes behind an <img> (a blob: or data: URL), read inside the page."""
    data_url = page.evaluate(
        """async (selector) => {
            const img = document.querySelector(selector);
            const blob = await (await fetch(img.src)).blob();
            return await new Promise((resolve) => {
                const reader = new FileReader();
                reader.onload = () => resolve(reader.result);
                reader.readAsDataURL(blob);
            });
        }""",
        selector,
    )
    return base64.b64decode(data_url.split(",", 1)[1])


@pytest.fixture(scope="package")
def service(tmp_path_factory: pytest.TempPathFactory) -> Iterator[LiveService]:
    """``sparsesplat serve`` (1 training + 1 render worker) on a free port, no API keys."""
    data = tmp_path_factory.mktemp("web") / "data"
    live = LiveService(data, env={"SPARSESPLAT_TORCH_THREADS": "2"})
    live.start_api()
    try:
        live.wait_ready()
        yield live
    finally:
        live.stop()
        if live.log.exists():
            ARTIFACTS.mkdir(parents=True, exist_ok=True)
            shutil.copy(live.log, ARTIFACTS / "service.log")


@pytest.fixture(scope="package")
def mic_folder(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """3 training + 2 held-out views of the shared Blender mic at 100x100 (cameras.json)."""
    if not MIC.is_dir():
        pytest.skip(f"shared scene missing: {MIC}")
    return write_mic_upload(tmp_path_factory.mktemp("mic") / "upload", size=100)


@pytest.fixture(scope="package")
def trained_job(
    browser: Any, service: LiveService, mic_folder: Path, artifacts: Path
) -> TrainedJob:
    """Submit the mic upload through the form (a 6 s time budget, a record every second), watch the
    job page while it trains (dropping the WebSocket once), until the job ends."""
    context, page, console = new_page(browser, service.url)
    page.goto("/")
    page.wait_for_selector("#job-form")
    files = [mic_folder / "cameras.json", *sorted(mic_folder.glob("*.png"))]
    page.set_input_files("#job-files", [str(f) for f in files])
    page.wait_for_selector("#job-submit:not([disabled])")
    summary = page.text_content("#upload-summary") or ""
    assert "5 frames (3 training, 2 held-out)" in summary
    assert "null" not in summary, summary
    # A time budget, so that the chart gains several live points on any machine (a count of
    # iterations finished between two records on a fast one).
    page.select_option("#job-length", "budget")
    page.fill("#job-length-value", str(FORM_BUDGET_S))
    page.fill("#job-record-interval", "1")
    page.click("#job-submit")
    page.wait_for_url(re.compile(r"#/jobs/job_[0-9a-f]+$"))
    job = TrainedJob(id=page.url.rsplit("/", 1)[1], state="queued")
    page.wait_for_selector("#job-state .badge")
    dropped = False
    deadline = time.monotonic() + 600
    while time.monotonic() < deadline:
        state = page.text_content("#job-state") or ""
        points = int(page.get_attribute("#job-chart", "data-points") or 0)
        job.seen.append((state, points))
        if state == "running" and points >= 1 and not dropped:
            page.evaluate("() => window.sparsesplat.events.drop()")  # as a network failure would
            dropped = True
        if state in TERMINAL:
            break
        time.sleep(0.5)
    job.state = page.text_content("#job-state") or ""
    if job.state != "succeeded":  # every test of the module needs the model: say why, fast
        error = page.text_content("#job-error") or ""
        page.screenshot(path=str(artifacts / "job-after-training.png"), full_page=True)
        context.close()
        pytest.fail(f"the smoke job {job.id} ended {job.state or 'unknown'}: {error}")
    page.wait_for_function("() => document.querySelector('#job-live').dataset.status == 'finished'")
    job.chart_points = int(page.get_attribute("#job-chart", "data-points") or 0)
    job.connections = int(page.evaluate("() => window.sparsesplat.events.connections"))
    job.api_key_in_session = page.evaluate("() => sessionStorage.getItem('sparsesplat.apiKey')")
    page.wait_for_function(
        "() => { const r = [...document.querySelectorAll('img.render')];"
        " return r.length === 5 && r.every((i) => i.dataset.ready === '1'); }"
    )
    job.photos = page.locator("img.photo").count()
    page.screenshot(path=str(artifacts / "job-after-training.png"), full_page=True)
    job.console_errors = list(console.errors)
    context.close()
    return job
