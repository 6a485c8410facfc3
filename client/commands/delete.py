"""``sparsesplat delete JOB``: delete a job and every file of it (cancelling it first)."""

from __future__ import annotations

import argparse
import json

from sparsesplat.client.commands.common import add_connection, client, guarded


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """The job id."""
    parser.add_argument("job", help="job id")
    add_connection(parser)


def run(args: argparse.Namespace) -> int:
    """Exit 0 once deleted, 4 if there was no such job."""

    def body() -> int:
        with client(args) as c:
            c.delete(args.job)
        print(json.dumps({"id": args.job, "deleted": True}) if args.json else f"{args.job} deleted")
        return 0

    return guarded(args, body)
