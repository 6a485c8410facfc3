"""``python -m sparsesplat.worker train|render|supervise``: one worker process.

``sparsesplat serve`` and ``sparsesplat worker`` start these; settings come from the
``SPARSESPLAT_*`` environment like everything else.
"""

from __future__ import annotations

import argparse
import sys

from sparsesplat.api.logs import configure_logging
from sparsesplat.api.settings import load_settings


def main(argv: list[str] | None = None) -> int:
    """Run the worker named by the first argument."""
    parser = argparse.ArgumentParser(prog="python -m sparsesplat.worker")
    parser.add_argument("kind", choices=["train", "render", "supervise"])
    parser.add_argument("--train", type=int, default=None, help="training workers (supervise)")
    parser.add_argument("--render", type=int, default=None, help="render workers (supervise)")
    args = parser.parse_args(argv)
    settings = load_settings()
    configure_logging(settings.log_level, json_lines=settings.log_json)
    if args.kind == "train":
        from sparsesplat.worker.training import TrainingWorker

        TrainingWorker(settings).run()
        return 0
    if args.kind == "render":
        from sparsesplat.worker.render_server import serve_renders

        serve_renders(settings)
        return 0
    from sparsesplat.worker.supervisor import Supervisor

    train = settings.workers if args.train is None else args.train
    render = settings.render_workers if args.render is None else args.render
    return Supervisor(train, render).run()


if __name__ == "__main__":
    sys.exit(main())
