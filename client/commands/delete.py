"""``sparsesplat delete JOB``: delete a job and every file of it (cancelling it first)."""

from __future__ import annotations

import argparse
import json

from sparsesplat.client.commands.common import add_job_arguments, run_on_job
from sparsesplat.client.sdk import Client


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """The job id."""
    add_job_arguments(parser)


def _delete(c: Client, job_id: str) -> tuple[str, str]:
    c.delete(job_id)
    return json.dumps({"id": job_id, "deleted": True}), f"{job_id} deleted"


def run(args: argparse.Namespace) -> int:
    """Exit 0 once deleted, 4 if there was no such job."""
    return run_on_job(args, _delete)
