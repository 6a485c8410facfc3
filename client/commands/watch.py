"""``sparsesplat watch JOB``: live events as a table (JSON lines with ``--json``)."""

from __future__ import annotations

import argparse
import sys

from sparsesplat.api.jobs import Event, JobState
from sparsesplat.client.commands.common import add_connection, client, fmt_seconds, guarded

COLUMNS = ("seq", "time", "event", "state/phase", "iteration", "elapsed", "psnr", "gaussians")
_WIDTHS = (5, 8, 8, 12, 11, 8, 7, 9)


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """The job id and where to start."""
    parser.add_argument("job", help="job id")
    parser.add_argument("--after", type=int, default=0, help="start after this event seq")
    parser.add_argument("--timeout", type=float, metavar="S", help="stop watching after S s")
    add_connection(parser)


def row(event: Event) -> list[str]:
    """Table cells of one event."""
    d = event.data
    state = str(d.get("state") or d.get("phase") or "")
    if event.type == "record" and d.get("views"):
        # Interim records score a few held-out views, the final one all: say which, so two
        # records at the last iteration with different PSNRs read as what they are.
        state = f"all {d['views']} views" if d.get("final") else f"{d['views']} views"
    if event.type == "warning":  # the message is the point of the event: give it the row
        return [str(event.seq), event.time.strftime("%H:%M:%S"), event.type, str(d.get("message"))]
    iteration = d.get("iteration")
    total = d.get("total")
    it = "" if iteration is None else (f"{iteration}/{total}" if total else str(iteration))
    psnr = d.get("psnr") if event.type == "record" else None
    return [
        str(event.seq),
        event.time.strftime("%H:%M:%S"),
        event.type,
        state,
        it,
        fmt_seconds(d.get("elapsed_s")),
        "" if psnr is None else f"{float(psnr):.2f}",
        "" if d.get("n_gaussians") is None else str(d["n_gaussians"]),
    ]


def _line(cells: list[str] | tuple[str, ...]) -> str:
    return "  ".join(c.ljust(w) for c, w in zip(cells, _WIDTHS, strict=False)).rstrip()


def run(args: argparse.Namespace) -> int:
    """Stream until the job ends: exit 0 succeeded, 1 failed or cancelled."""

    def body() -> int:
        with client(args) as c:
            if not args.json:
                print(_line(COLUMNS), flush=True)
            for event in c.events(args.job, args.after, timeout=args.timeout):
                print(event.model_dump_json() if args.json else _line(row(event)), flush=True)
            job = c.get_job(args.job)
        for message in job.warnings:
            print(f"warning: {job.id}: {message}", file=sys.stderr)
        if job.state != JobState.succeeded:
            if job.error:
                print(f"{job.id} {job.state.value}: {job.error}", file=sys.stderr)
            return 1
        return 0

    return guarded(args, body)
