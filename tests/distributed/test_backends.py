"""The service issue's end-to-end test, unchanged, on both backends: upload 3 views + held-out
views, stream events to completion, render a held-out pose equal to the trainer's own
evaluation render, download the .ply.

The embedded case is the very test ``tests/service/test_end_to_end.py`` runs in the default
suite, so here it runs with ``-m slow`` only (the pair then runs side by side); the default
suite runs the Celery + PostgreSQL case.
"""

from __future__ import annotations

from pathlib import Path

import pytest

from tests.distributed.conftest import make_service
from tests.service.test_end_to_end import test_upload_train_stream_render_export as end_to_end

pytestmark = pytest.mark.shared_data


@pytest.mark.parametrize("backend", [pytest.param("embedded", marks=pytest.mark.slow), "celery"])
def test_end_to_end_on_each_backend(
    backend: str, tmp_path: Path, mic_upload: Path, request: pytest.FixtureRequest
) -> None:
    postgres = redis = None
    if backend == "celery":
        postgres = request.getfixturevalue("postgres")
        redis = request.getfixturevalue("redis_server")
    live = make_service(backend, tmp_path / "data", postgres, redis)
    try:
        end_to_end(live, mic_upload)
    finally:
        live.stop()
