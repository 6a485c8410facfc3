"""A real S3-protocol server (moto's, on loopback) for the artifact store's tests."""

from __future__ import annotations

from collections.abc import Iterator

import pytest

from tests.artifacts.moto_s3 import MotoS3, start_moto


@pytest.fixture(scope="session")
def s3(tmp_path_factory: pytest.TempPathFactory) -> Iterator[MotoS3]:
    """moto's S3 server for the session (skips when moto[server] / boto3 are missing)."""
    try:
        server = start_moto(tmp_path_factory.mktemp("moto") / "moto.log")
    except ImportError as exc:
        pytest.skip(f"{exc.name} missing: pip install 'moto[server]' boto3 (the dev extra)")
    yield server
    server.stop()
