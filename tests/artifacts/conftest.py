"""A real S3-protocol server (moto's, on loopback) for the artifact store's tests."""

from __future__ import annotations

import pytest

from tests.artifacts.moto_s3 import moto_fixture

s3 = pytest.fixture(scope="session", name="s3")(moto_fixture)
"""moto's S3 server for the session (tests.artifacts.moto_s3)."""
