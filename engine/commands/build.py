"""``sparsesplat build``: compile the native CPU kernels now, not at the first job or render.

``make run`` runs it during set-up, and ``sparsesplat serve`` runs it before its workers start
(writing ``<data_dir>/kernels.json``, which ``/healthz`` and ``/readyz`` report). pip users run
it once after installing or updating. A build that is already cached only loads (seconds).
Exit codes: 0 built or loaded, 1 a build failed (the compiler's output is printed).
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """Options of ``sparsesplat build``."""
    parser.add_argument(
        "--status-file", type=Path, default=None,
        help="write the build's progress to this JSON file (the service's data folder's "
             "kernels.json is what /healthz reads)",
    )  # fmt: skip
    parser.add_argument("--json", action="store_true", help="print one JSON line at the end")


def run(args: argparse.Namespace) -> int:
    """Build or load every kernel, printing each one's variant and seconds."""
    from sparsesplat.engine.errors import EngineError
    from sparsesplat.engine.kernels import build_all

    started = time.monotonic()

    def each(name: str, variant: str, seconds: float) -> None:
        if not args.json:
            print(f"{name:<18} {variant:<8} {seconds:6.1f} s", flush=True)

    if not args.json:
        print("sparsesplat: building the native CPU kernels (cached; minutes only the first "
              "time after install or update)", flush=True)  # fmt: skip
    try:
        variants = build_all(args.status_file, on_each=each)
    except EngineError as exc:
        print(f"sparsesplat build: {exc}", file=sys.stderr)
        return 1
    total = time.monotonic() - started
    if args.json:
        print(json.dumps({"variants": variants, "seconds": round(total, 1)}))
    else:
        print(f"ready in {total:.1f} s")
    return 0
