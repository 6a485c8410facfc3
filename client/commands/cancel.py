"""``sparsesplat cancel JOB``: stop a job (a running one at its next iteration)."""

from __future__ import annotations

import argparse

from sparsesplat.client.commands.common import add_connection, client, dump, guarded


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """The job id."""
    parser.add_argument("job", help="job id")
    add_connection(parser)


def run(args: argparse.Namespace) -> int:
    """Print the job's state after the request."""

    def body() -> int:
        with client(args) as c:
            job = c.cancel(args.job)
        print(dump(job) if args.json else f"{job.id} {job.state.value}")
        return 0

    return guarded(args, body)
