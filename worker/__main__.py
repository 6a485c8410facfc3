"""``python -m sparsesplat.worker train|render|supervise``: one worker process.

``sparsesplat serve`` and ``sparsesplat worker`` start these; settings come from the
``SPARSESPLAT_*`` environment like everything else. ``train`` is a polling training worker
with the embedded queue (``queue=local``) and a Celery node consuming the training queue with
``queue=celery`` (``--concurrency`` pool processes, one job each at a time).
"""

from __future__ import annotations

import argparse
import logging
import os
import signal
import socket
import sys
import threading
import time

from sparsesplat.api import faults
from sparsesplat.api.logs import configure_logging
from sparsesplat.api.settings import QueueBackend, Settings, load_settings


def main(argv: list[str] | None = None) -> int:
    """Run the worker named by the first argument."""
    parser = argparse.ArgumentParser(prog="python -m sparsesplat.worker")
    parser.add_argument("kind", choices=["train", "render", "supervise"])
    parser.add_argument("--train", type=int, default=None, help="training workers (supervise)")
    parser.add_argument("--render", type=int, default=None, help="render workers (supervise)")
    parser.add_argument(
        "--concurrency", type=int, default=1, help="pool processes of a Celery node (train)"
    )
    args = parser.parse_args(argv)
    settings = load_settings()
    configure_logging(settings.log_level, json_lines=settings.log_json)
    faults.install(with_torch=args.kind == "train")  # tests only (SPARSESPLAT_TEST_FAULTS_FILE)
    if args.kind == "train" and settings.queue == QueueBackend.celery:
        return run_celery_node(settings, args.concurrency)
    if args.kind == "train":
        from sparsesplat.worker.training import TrainingWorker

        TrainingWorker(settings).run()
        return 0
    if args.kind == "render":
        from sparsesplat.worker.render_server import serve_renders

        serve_renders(settings)
        return 0
    from sparsesplat.worker.supervisor import Supervisor, requeue_jobs_of_dead_workers

    train = settings.workers if args.train is None else args.train
    render = settings.render_workers if args.render is None else args.render
    on_exit = None
    if settings.queue != QueueBackend.celery and settings.database_url is not None:
        # Embedded queue: the supervisor re-queues a dead worker's job at once. (With Celery
        # the API re-dispatches expired jobs; a job queued without a message would wait.)
        on_exit = requeue_jobs_of_dead_workers(settings.database_url, settings.max_attempts)
    return Supervisor(train, render, on_exit).run()


def run_celery_node(settings: Settings, concurrency: int = 1) -> int:
    """A Celery worker node on the training queue until SIGTERM (warm shutdown: a running job
    checkpoints and goes back to the queue)."""
    from sparsesplat.api.store.broker import TRAIN_QUEUE
    from sparsesplat.worker.celery_app import app
    from sparsesplat.worker.kernels import prepare_kernels

    prepare_kernels(settings)  # before the node consumes: no task waits on the compiler
    parent = os.getppid()

    def watch_parent() -> None:  # the supervisor died: warm shutdown, do not linger as an orphan
        while os.getppid() == parent:
            time.sleep(1.0)
        logging.getLogger("sparsesplat.worker").warning("parent process gone; stopping")
        os.kill(os.getpid(), signal.SIGTERM)

    # Started before the pool forks: a thread does not survive into the forked children.
    threading.Thread(target=watch_parent, name="parent-watch", daemon=True).start()
    app.worker_main(
        [
            "worker",
            f"--queues={TRAIN_QUEUE}",
            f"--concurrency={max(1, concurrency)}",
            "--prefetch-multiplier=1",
            "--max-tasks-per-child=1",
            "--pool=prefork",
            "-O", "fair",
            f"--hostname=train-{os.getpid()}@{socket.gethostname()}",
            f"--loglevel={settings.log_level}",
            "--without-mingle",
            "--without-gossip",
        ]
    )  # fmt: skip
    return 0


if __name__ == "__main__":
    sys.exit(main())
