"""``sparsesplat usage``: the bytes and jobs your key holds, against the service's limits."""

from __future__ import annotations

import argparse

from sparsesplat.api.usage import Usage
from sparsesplat.client.commands.common import add_connection, client, dump, guarded


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """The connection options."""
    add_connection(parser)


def _of(value: float, limit: float | None, unit: str = "") -> str:
    return f"{value:g}{unit}" + (f" of {limit:g}{unit}" if limit is not None else " (no limit)")


def describe(usage: Usage) -> str:
    """Human-readable lines."""
    limit_mb = None if usage.stored_limit_bytes is None else usage.stored_limit_bytes / 1e6
    ttl = "kept for good" if usage.model_ttl_days is None else (
        f"unpinned models expire {usage.model_ttl_days:g} days after training"
    )  # fmt: skip
    return "\n".join(
        [
            f"key             {usage.owner}",
            f"stored          {_of(round(usage.stored_bytes / 1e6, 1), limit_mb, ' MB')}",
            f"jobs            {_of(usage.jobs, usage.jobs_limit)}",
            f"active jobs     {_of(usage.active_jobs, usage.active_jobs_limit)}",
            f"models          {usage.models} ({usage.pinned_models} pinned; {ttl})",
        ]
    )


def run(args: argparse.Namespace) -> int:
    """Print the usage; exit 0."""

    def body() -> int:
        with client(args) as c:
            usage = c.usage()
        print(dump(usage) if args.json else describe(usage))
        return 0

    return guarded(args, body)
