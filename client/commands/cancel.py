"""``sparsesplat cancel JOB``: stop a job (a running one at its next iteration)."""

from __future__ import annotations

import argparse

from sparsesplat.client.commands.common import add_job_arguments, dump, run_on_job
from sparsesplat.client.sdk import Client


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """The job id."""
    add_job_arguments(parser)


def _cancel(c: Client, job_id: str) -> tuple[str, str]:
    job = c.cancel(job_id)
    return dump(job), f"{job.id} {job.state.value}"


def run(args: argparse.Namespace) -> int:
    """Print the job's state after the request."""
    return run_on_job(args, _cancel)
