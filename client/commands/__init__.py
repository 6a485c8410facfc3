"""``sparsesplat health``: the SDK from the command line."""

from __future__ import annotations

import argparse
import sys


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """``--url`` of the service (default SPARSESPLAT_URL or http://127.0.0.1:8000)."""
    parser.add_argument("--url", help="service base URL")


def run(args: argparse.Namespace) -> int:
    """Print the health answer; exit 1 when the service cannot be reached."""
    from sparsesplat.client import Client, SparsesplatError

    try:
        with Client(args.url) as client:
            health = client.health()
    except SparsesplatError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 1
    print(health.model_dump_json())
    return 0
