"""``sparsesplat worker``: run worker processes without the API (a second machine, compose).

With ``SPARSESPLAT_QUEUE=celery`` each training worker is a Celery node on the training queue
(a second machine needs only the database and broker URLs and the shared data directory).
Render workers listen on loopback for the API on their own machine, so with Celery they run
only when asked for (``--render N`` on the API's machine; ``sparsesplat serve`` starts them).
"""

from __future__ import annotations

import argparse
import sys


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """Options override the matching ``SPARSESPLAT_*`` settings."""
    parser.add_argument("--train", type=int, help="training workers (SPARSESPLAT_WORKERS)")
    parser.add_argument(
        "--render", type=int,
        help="render workers (SPARSESPLAT_RENDER_WORKERS; with SPARSESPLAT_QUEUE=celery the "
        "default is 0: they serve the API on their own machine only)",
    )  # fmt: skip


def run(args: argparse.Namespace) -> int:
    """Migrate the database if needed, then supervise the workers until interrupted."""
    from sparsesplat.api.logs import configure_logging
    from sparsesplat.api.settings import QueueBackend, load_settings
    from sparsesplat.api.store.database import make_engine, migrate
    from sparsesplat.worker.supervisor import Supervisor, requeue_jobs_of_dead_workers

    settings = load_settings()
    configure_logging(settings.log_level, json_lines=settings.log_json)
    if settings.queue == QueueBackend.celery:
        try:
            import celery  # noqa: F401

            if str(settings.database_url).startswith("postgres"):
                import psycopg  # noqa: F401
        except ImportError:
            from sparsesplat.api.store.broker import MISSING_EXTRA

            print(f"sparsesplat worker: {MISSING_EXTRA}", file=sys.stderr)
            return 3
    assert settings.database_url is not None
    migrate(make_engine(settings.database_url))
    train = settings.workers if args.train is None else args.train
    render = settings.render_workers if args.render is None else args.render
    if args.render is None and settings.queue == QueueBackend.celery:
        render = 0
    on_exit = None
    if settings.queue != QueueBackend.celery and settings.database_url is not None:
        # Embedded queue: the supervisor re-queues a dead worker's job at once. (With Celery
        # the API re-dispatches expired jobs; a job queued without a message would wait.)
        on_exit = requeue_jobs_of_dead_workers(settings.database_url, settings.max_attempts)
    return Supervisor(train, render, on_exit).run()
