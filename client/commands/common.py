"""What every client command shares: connection options, ``--json``, error messages and the
exit codes scripts rely on (:data:`sparsesplat.client.errors.EXIT_CODES`):

====  =====================================================================
code  meaning
====  =====================================================================
0     success (``submit --wait`` / ``watch``: the job succeeded)
1     the job failed or was cancelled; any other error
2     bad usage, or input refused (locally or by the server: 400/413/422)
3     a needed extra is not installed (the message names it)
4     no such job or model (404)
5     authentication failed (401/403: missing, unknown or revoked key)
6     conflict (409): e.g. rendering a job that has not succeeded yet
7     rate limited (429)
8     server error (5xx)
9     the server cannot be reached
10    timed out
130   interrupted (Ctrl-C)
====  =====================================================================

Errors print one line on stderr, ``error: <message>``; with ``--json`` also a JSON object
``{"error": {"kind", "status", "code", "message"}}`` on stdout.
"""

from __future__ import annotations

import argparse
import json
import sys
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

from pydantic import BaseModel

from sparsesplat.client.errors import APIError, InvalidInput, SparsesplatError, exit_code
from sparsesplat.client.sdk import Client, Timeouts


def add_connection(parser: argparse.ArgumentParser, json_flag: bool = True) -> None:
    """``--url``, ``--api-key``, ``--timeout`` and (for read commands) ``--json``."""
    group = parser.add_argument_group("connection")
    group.add_argument("--url", help="service URL (default SPARSESPLAT_URL or 127.0.0.1:8000)")
    group.add_argument("--api-key", help="API key (default SPARSESPLAT_API_KEY)")
    group.add_argument(
        "--request-timeout", type=float, metavar="S", help="seconds per request (default 30)"
    )
    if json_flag:
        parser.add_argument(
            "--json", action="store_true", help="print machine-readable JSON on stdout"
        )


def add_job_arguments(parser: argparse.ArgumentParser) -> None:
    """The positional job id and the connection options (the commands that act on one job)."""
    parser.add_argument("job", help="job id")
    add_connection(parser)


def json_argument(value: str, option: str, inline: tuple[str, ...]) -> Any:
    """The JSON an option gives: ``value`` itself when it starts with one of ``inline`` (e.g.
    ``{``), else the file it names; InvalidInput naming ``option`` when unreadable or not
    JSON."""
    text = value.strip()
    if not text.startswith(inline):
        try:
            text = Path(value).read_text()
        except OSError as exc:
            raise InvalidInput(f"{option} {value}: cannot read ({exc})") from exc
    try:
        return json.loads(text)
    except json.JSONDecodeError as exc:
        raise InvalidInput(f"{option}: not valid JSON ({exc})") from exc


def client(args: argparse.Namespace) -> Client:
    """A client for the command's connection options."""
    timeouts = None
    if getattr(args, "request_timeout", None):
        t = float(args.request_timeout)
        timeouts = Timeouts(read=t, render=max(t, Timeouts.render))
    return Client(args.url, args.api_key, timeouts=timeouts)


def dump(value: Any) -> str:
    """JSON text of pydantic models, lists of them, or plain data."""
    if isinstance(value, BaseModel):
        return value.model_dump_json()
    if isinstance(value, list):
        return "[" + ", ".join(dump(v) for v in value) + "]"
    return json.dumps(value, default=str)


def guarded(args: argparse.Namespace, body: Callable[[], int]) -> int:
    """Run ``body``; an SDK error prints its message and becomes its exit code."""
    try:
        return body()
    except SparsesplatError as exc:
        print(f"error: {exc}", file=sys.stderr)
        if getattr(args, "json", False):
            error: dict[str, Any] = {"kind": type(exc).__name__, "message": str(exc)}
            if isinstance(exc, APIError):
                error.update(status=exc.status, code=exc.code, message=exc.message)
            print(json.dumps({"error": error}))
        return exit_code(exc)
    except KeyboardInterrupt:
        return 130


def run_on_job(args: argparse.Namespace, act: Callable[[Client, str], tuple[str, str]]) -> int:
    """Run ``act(client, job_id)`` under :func:`guarded`; it returns its outcome as a (JSON,
    human-readable) pair of lines, and the one ``--json`` asks for is printed."""

    def body() -> int:
        with client(args) as c:
            as_json, human = act(c, args.job)
        print(as_json if args.json else human)
        return 0

    return guarded(args, body)


def table(rows: Sequence[Sequence[Any]], header: Sequence[str]) -> str:
    """Plain text columns, left-aligned."""
    cells = [[str(c) for c in header]] + [[("" if c is None else str(c)) for c in r] for r in rows]
    widths = [max(len(r[i]) for r in cells) for i in range(len(header))]
    return "\n".join(
        "  ".join(c.ljust(w) for c, w in zip(r, widths, strict=True)).rstrip() for r in cells
    )


def fmt_seconds(value: float | None) -> str:
    """``1m05s`` style."""
    if value is None:
        return ""
    value = max(0.0, float(value))
    if value < 60:
        return f"{value:.0f}s"
    minutes, seconds = divmod(int(value), 60)
    if minutes < 60:
        return f"{minutes}m{seconds:02d}s"
    hours, minutes = divmod(minutes, 60)
    return f"{hours}h{minutes:02d}m"
