"""``sparsesplat serve``: the HTTP service plus its local worker processes (embedded defaults)."""

from __future__ import annotations

import argparse
import os
import subprocess
import sys

SHUTDOWN_GRACE_S = 5
"""Seconds open connections (event streams) get to finish when the server stops."""


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """Options override the matching ``SPARSESPLAT_*`` settings."""
    parser.add_argument("--host", help="bind address (SPARSESPLAT_HOST, default 127.0.0.1)")
    parser.add_argument("--port", type=int, help="TCP port (SPARSESPLAT_PORT, default 8000)")
    parser.add_argument("--data-dir", help="local storage root (SPARSESPLAT_DATA_DIR)")
    parser.add_argument(
        "--workers", type=int, help="training worker processes (SPARSESPLAT_WORKERS, default 1)"
    )
    parser.add_argument(
        "--render-workers", type=int,
        help="render worker processes (SPARSESPLAT_RENDER_WORKERS, default 1)",
    )  # fmt: skip


def run(args: argparse.Namespace) -> int:
    """Migrate the database, start the workers, serve HTTP until interrupted."""
    import uvicorn

    from sparsesplat.api import faults
    from sparsesplat.api.logs import configure_logging
    from sparsesplat.api.settings import load_settings
    from sparsesplat.api.store.database import make_engine, migrate
    from sparsesplat.api.store.keys import KeyStore
    from sparsesplat.server.app import create_app
    from sparsesplat.server.auth import InsecureExposure, check_exposure

    overrides = {
        key: value
        for key, value in {
            "host": args.host,
            "port": args.port,
            "data_dir": args.data_dir,
            "workers": args.workers,
            "render_workers": args.render_workers,
        }.items()
        if value is not None
    }
    settings = load_settings(**overrides)
    configure_logging(settings.log_level, json_lines=settings.log_json)
    faults.install()  # tests only (SPARSESPLAT_TEST_FAULTS_FILE)
    assert settings.database_url is not None
    engine = make_engine(settings.database_url)
    migrate(engine)
    try:
        check_exposure(settings, KeyStore(engine))
    except InsecureExposure as exc:
        print(f"sparsesplat serve: {exc}", file=sys.stderr)
        return 2
    finally:
        engine.dispose()
    workers = None
    if settings.workers + settings.render_workers > 0:
        # A separate process tree (no import of the worker package: the server stays torch-free).
        workers = subprocess.Popen(
            [sys.executable, "-m", "sparsesplat.worker", "supervise"],
            env={**os.environ, **settings.environment()},
        )
    try:
        # Event streams stay open until their job ends: on shutdown, give them a few seconds to
        # finish (clients resume with ?after=) instead of waiting for every job to complete.
        uvicorn.run(
            create_app(settings), host=settings.host, port=settings.port, log_config=None,
            access_log=True, timeout_graceful_shutdown=SHUTDOWN_GRACE_S,
        )  # fmt: skip
    finally:
        if workers is not None:
            workers.terminate()
            try:
                workers.wait(timeout=90)
            except subprocess.TimeoutExpired:
                workers.kill()
    return 0
