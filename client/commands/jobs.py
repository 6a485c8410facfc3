"""``sparsesplat jobs``: your jobs, newest first."""

from __future__ import annotations

import argparse

from sparsesplat.api.jobs import Job
from sparsesplat.client.commands.common import add_connection, client, dump, guarded, table


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """Filter and page size."""
    parser.add_argument(
        "--state", choices=["queued", "running", "succeeded", "failed", "cancelled"]
    )
    parser.add_argument("--limit", type=int, default=20, help="how many (default 20)")
    parser.add_argument("--all", action="store_true", help="every job, across pages")
    add_connection(parser)


def _progress(job: Job) -> str:
    p = job.progress
    if p is None:
        return "" if job.queue_position is None else f"queue #{job.queue_position}"
    return f"{p.iteration}/{p.total}" if p.total else str(p.iteration)


def run(args: argparse.Namespace) -> int:
    """Print a table (or a JSON list)."""

    def body() -> int:
        with client(args) as c:
            if args.all:
                found = list(c.iter_jobs(args.state))
            else:
                found = c.jobs(args.state, limit=args.limit).jobs
        if args.json:
            print(dump(found))
            return 0
        rows = [
            (
                j.id,
                j.state.value,
                j.created_at.strftime("%Y-%m-%d %H:%M:%S"),
                _progress(j),
                f"{j.n_train_views}+{j.n_test_views}",
                (j.error or "")[:60],
            )
            for j in found
        ]
        print(table(rows, ("id", "state", "created (UTC)", "progress", "views", "error")))
        return 0

    return guarded(args, body)
