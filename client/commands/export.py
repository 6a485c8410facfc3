"""``sparsesplat export MODEL --format ply|splat|checkpoint [-o OUT]``: download a model."""

from __future__ import annotations

import argparse
import json
from pathlib import Path

from sparsesplat.api.names import EXPORT_SUFFIXES
from sparsesplat.client.commands.common import add_connection, client, guarded


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """Model id, format and output path."""
    parser.add_argument("model", help="model id (the job id)")
    parser.add_argument(
        "--format", choices=sorted(EXPORT_SUFFIXES), default="ply", help="default ply"
    )
    parser.add_argument("-o", "--output", help="output file (default MODEL.<format suffix>)")
    add_connection(parser)


def run(args: argparse.Namespace) -> int:
    """Write the file; print its path (or JSON with path and size)."""

    def body() -> int:
        out = Path(args.output or f"{args.model}{EXPORT_SUFFIXES[args.format]}")
        with client(args) as c:
            path = c.model(args.model).export(args.format, out)
        if args.json:
            print(json.dumps({"path": str(path), "bytes": path.stat().st_size}))
        else:
            print(path)
        return 0

    return guarded(args, body)
