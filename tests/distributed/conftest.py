"""Fixtures for the scale-out backend: a private PostgreSQL and Redis for the session, and a
service (``sparsesplat serve`` + ``sparsesplat worker`` as real processes) on either backend.

When PostgreSQL, Redis or the ``distributed`` extra is missing, the tests that need them skip
and say why (``.ci/run`` installs and starts what they need on a fresh Debian machine).
"""

from __future__ import annotations

import itertools
import uuid
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import TypeVar

import pytest

from tests.artifacts.moto_s3 import moto_fixture
from tests.distributed.servers import PostgresServer, RedisServer, Unavailable
from tests.service.live import LiveService
from tests.service.scenes import MIC, write_mic_upload

_names = itertools.count(1)

_Server = TypeVar("_Server", PostgresServer, RedisServer)


def _need_extra() -> None:
    for module in ("celery", "redis", "psycopg"):
        try:
            __import__(module)
        except ImportError:
            pytest.skip(f"{module} missing: pip install 'sparsesplat[distributed]'")


def _private_server(make: Callable[[], _Server], what: str) -> Iterator[_Server]:
    """Start a server private to this test session; skip when ``what`` is unavailable."""
    _need_extra()
    try:
        server = make()
    except (Unavailable, OSError) as exc:
        pytest.skip(f"{what} unavailable: {exc}")
    try:
        server.start()
    except (Unavailable, OSError) as exc:
        server.close()
        pytest.skip(f"{what} unavailable: {exc}")
    yield server
    server.close()


@pytest.fixture(scope="session")
def postgres() -> Iterator[PostgresServer]:
    """A PostgreSQL server private to this test session."""
    yield from _private_server(PostgresServer, "PostgreSQL")


@pytest.fixture(scope="session")
def redis_server() -> Iterator[RedisServer]:
    """A Redis server private to this test session (no persistence)."""
    yield from _private_server(RedisServer, "Redis")


s3 = pytest.fixture(scope="session", name="s3")(moto_fixture)
"""moto's S3 server for the session, for job files in a bucket (tests.artifacts.moto_s3)."""


@pytest.fixture(scope="session")
def mic_upload(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """3 training + 2 held-out views of the shared Blender mic, 100x100 (as in tests/service)."""
    if not MIC.is_dir():
        pytest.skip(f"shared scene missing: {MIC}")
    return write_mic_upload(tmp_path_factory.mktemp("mic") / "upload", size=100)


def celery_env(postgres: PostgresServer, redis_server: RedisServer) -> dict[str, str]:
    """What a user sets for the scale-out backend: the queue, a database URL, a broker URL
    (a fresh database and Redis database number, so services never share state)."""
    database = f"t{next(_names)}_{uuid.uuid4().hex[:8]}"
    return {
        "SPARSESPLAT_QUEUE": "celery",
        "SPARSESPLAT_DATABASE_URL": postgres.create_database(database),
        "SPARSESPLAT_BROKER_URL": redis_server.url(),
    }


def make_service(
    backend: str, data_dir: Path, postgres: PostgresServer | None, redis: RedisServer | None
) -> LiveService:
    """A (not yet started) service on ``backend``: ``embedded`` or ``celery``."""
    if backend == "embedded":
        return LiveService(data_dir)
    assert postgres is not None and redis is not None
    return LiveService(data_dir, celery_env(postgres, redis))
