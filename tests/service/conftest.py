"""Fixtures for the service tests: a smoke-scale upload and a live service."""

from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path

import pytest

from tests.service.live import LiveService
from tests.service.scenes import MIC, write_mic_upload


@pytest.fixture(scope="session")
def mic_upload(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """3 training + 2 held-out views of the shared Blender mic, 100x100, OpenGL c2w."""
    if not MIC.is_dir():
        pytest.skip(f"shared scene missing: {MIC}")
    return write_mic_upload(tmp_path_factory.mktemp("mic") / "upload", size=100)


@pytest.fixture
def live(tmp_path: Path) -> Iterator[LiveService]:
    """A service over a fresh data directory (not started: each test starts what it needs)."""
    service = LiveService(tmp_path / "data")
    yield service
    service.stop()
