"""The service issue's end-to-end test, unchanged, on both backends: upload 3 views + held-out
views, stream events to completion, render a held-out pose equal to the trainer's own
evaluation render, download the .ply. (The embedded case repeats tests/service's own run of it,
side by side with the Celery + PostgreSQL case: about half a minute on an idle machine.)
"""

from __future__ import annotations

from pathlib import Path

import pytest

from tests.distributed.conftest import make_service
from tests.service.test_end_to_end import test_upload_train_stream_render_export as end_to_end

pytestmark = pytest.mark.shared_data


@pytest.mark.parametrize("backend", ["embedded", "celery"])
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
