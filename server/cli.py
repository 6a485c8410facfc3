"""``sparsesplat serve``: run the HTTP service with uvicorn."""

from __future__ import annotations

import argparse


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """Options override the matching ``SPARSESPLAT_*`` settings."""
    parser.add_argument("--host", help="bind address (SPARSESPLAT_HOST, default 127.0.0.1)")
    parser.add_argument("--port", type=int, help="TCP port (SPARSESPLAT_PORT, default 8000)")
    parser.add_argument("--data-dir", help="local storage root (SPARSESPLAT_DATA_DIR)")
    parser.add_argument("--workers", type=int, help="local worker processes (SPARSESPLAT_WORKERS)")


def run(args: argparse.Namespace) -> int:
    """Start uvicorn in this process and serve until interrupted."""
    import uvicorn

    from sparsesplat.api.logs import configure_logging
    from sparsesplat.api.settings import load_settings
    from sparsesplat.server.app import create_app

    overrides = {
        key: value
        for key, value in {
            "host": args.host,
            "port": args.port,
            "data_dir": args.data_dir,
            "workers": args.workers,
        }.items()
        if value is not None
    }
    settings = load_settings(**overrides)
    configure_logging(settings.log_level, json_lines=settings.log_json)
    app = create_app(settings)
    uvicorn.run(app, host=settings.host, port=settings.port, log_config=None, access_log=True)
    return 0
