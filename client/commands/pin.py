"""``sparsesplat pin MODEL``: keep a model past the service's expiry (``--off``: let it go)."""

from __future__ import annotations

import argparse

from sparsesplat.client.commands.common import add_job_arguments, run_on_job
from sparsesplat.client.sdk import Client


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """The model id and ``--off``."""
    add_job_arguments(parser)
    parser.add_argument("--off", action="store_true", help="unpin: the model expires again")


def run(args: argparse.Namespace) -> int:
    """Exit 0 once (un)pinned, 4 if there is no such model (or it expired)."""
    pinned = not args.off

    def act(c: Client, model_id: str) -> tuple[str, str]:
        info = c.model(model_id).pin(pinned)
        until = (
            "" if info.expires_at is None else f" (expires {info.expires_at:%Y-%m-%d %H:%M} UTC)"
        )
        return info.model_dump_json(), f"{model_id} {'pinned' if pinned else 'unpinned'}{until}"

    return run_on_job(args, act)
