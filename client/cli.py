"""The ``sparsesplat`` command. Subcommands live in their own modules and load lazily, so
``sparsesplat --help`` and the SDK commands work on an SDK-only install, and a command whose
extra is missing says exactly what to install."""

from __future__ import annotations

import argparse
import importlib
import os
import sys
from dataclasses import dataclass
from types import ModuleType

from sparsesplat import __version__


@dataclass(frozen=True)
class Command:
    """A subcommand: the module implementing it and the extra it needs."""

    module: str
    """Module exposing ``add_arguments(parser)`` and ``run(args) -> int``."""
    help: str
    """One-line description for ``--help``."""
    extra: str | None
    """pip extra that provides its dependencies (None: the base install suffices)."""


COMMANDS: dict[str, Command] = {
    "serve": Command(
        "sparsesplat.server.cli", "run the HTTP service (embedded defaults)", "service"
    ),
    "worker": Command(
        "sparsesplat.worker.cli", "run training and render workers (no API)", "service"
    ),
    "keys": Command("sparsesplat.server.keys_cli", "manage API keys (on the server)", "service"),
    "health": Command(
        "sparsesplat.client.commands", "ask a running service whether it is up", None
    ),
    "submit": Command(
        "sparsesplat.client.commands.submit", "upload a scene folder or images as a job", None
    ),
    "status": Command("sparsesplat.client.commands.status", "show a job's state", None),
    "watch": Command("sparsesplat.client.commands.watch", "follow a job's live events", None),
    "jobs": Command("sparsesplat.client.commands.jobs", "list your jobs", None),
    "export": Command(
        "sparsesplat.client.commands.export", "download a model (.ply, .splat, checkpoint)", None
    ),
    "cancel": Command("sparsesplat.client.commands.cancel", "cancel a job", None),
    "delete": Command("sparsesplat.client.commands.delete", "delete a job and its files", None),
    "usage": Command(
        "sparsesplat.client.commands.usage",
        "your key's stored bytes and jobs, and its limits",
        None,
    ),
    "pin": Command(
        "sparsesplat.client.commands.pin", "keep a model past expiry (--off: let it expire)", None
    ),
    "scene": Command(
        "sparsesplat.engine.commands.scene",
        "inspect a scene folder: split, cameras, background, the preset train would choose",
        "engine",
    ),
    "train": Command(
        "sparsesplat.engine.commands.train",
        "train a scene locally (preset chosen from the scene; --help lists presets and priors)",
        "engine",
    ),
    "build": Command(
        "sparsesplat.engine.commands.build",
        "compile the native CPU kernels now (once after install or update; serve does it too)",
        "engine",
    ),
    "cameras": Command(
        "sparsesplat.engine.commands.cameras",
        "estimate the cameras of photos without poses (writes cameras.json; sfm extra)",
        "sfm",
    ),
    "render": Command(
        "sparsesplat.client.commands.render",
        "render a model on the service, or a local checkpoint (engine extra); camera JSON "
        "with convention and pose, see --help",
        None,
    ),
    "fetch-weights": Command(
        "sparsesplat.client.fetch_weights", "download LPIPS weights (needs network)", None
    ),
}

# Third-party top-level modules each extra brings; a missing one means the extra is missing.
_EXTRA_MODULES = {
    "torch",
    "numpy",
    "PIL",
    "skimage",
    "onnxruntime",
    "matplotlib",
    "fastapi",
    "uvicorn",
    "starlette",
}


LOCAL_COMMANDS = frozenset({"scene", "train", "cameras", "render", "fetch-weights", "health"})
"""Commands that run in the foreground and log through :func:`configure_cli_logging` (the
service commands configure logging from their settings)."""


def configure_cli_logging() -> None:
    """Send log records to stderr, one line each: ``SPARSESPLAT_LOG_LEVEL`` (default WARNING
    for local commands, INFO shows e.g. the native extension loads) and
    ``SPARSESPLAT_LOG_JSON`` (default false here: human-readable key=value lines)."""
    from sparsesplat.api.logs import configure_logging

    level = os.environ.get("SPARSESPLAT_LOG_LEVEL", "WARNING").strip().upper() or "WARNING"
    if level not in ("DEBUG", "INFO", "WARNING", "ERROR", "CRITICAL"):
        print(
            f"sparsesplat: SPARSESPLAT_LOG_LEVEL={level!r} is not a level (DEBUG, INFO, "
            "WARNING, ERROR); using WARNING",
            file=sys.stderr,
        )
        level = "WARNING"
    json_lines = os.environ.get("SPARSESPLAT_LOG_JSON", "false").strip().lower() in (
        "1",
        "true",
        "yes",
        "on",
    )
    configure_logging(level, json_lines=json_lines)


def _missing_extra_message(name: str, command: Command, exc: ModuleNotFoundError) -> str:
    return (
        f"sparsesplat {name}: needs the '{command.extra}' extra (missing module {exc.name!r}). "
        f"Install it with: pip install 'sparsesplat[{command.extra}]'"
    )


def _load(name: str) -> ModuleType:
    return importlib.import_module(COMMANDS[name].module)


def build_parser(argv: list[str]) -> argparse.ArgumentParser:
    """The top-level parser; only the chosen subcommand's module is imported."""
    parser = argparse.ArgumentParser(prog="sparsesplat", description=__doc__)
    parser.add_argument("--version", action="version", version=f"sparsesplat {__version__}")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    chosen = next((a for a in argv if a in COMMANDS), None)
    for name, command in COMMANDS.items():
        sub_parser = sub.add_parser(name, help=command.help, description=command.help)
        if name == chosen:
            _load(name).add_arguments(sub_parser)
    return parser


def main(argv: list[str] | None = None) -> int:
    """Entry point of the console script."""
    argv = list(sys.argv[1:] if argv is None else argv)
    try:
        parser = build_parser(argv)
        args = parser.parse_args(argv)
        if args.command is None:
            parser.print_help()
            return 2
        if args.command in LOCAL_COMMANDS:
            configure_cli_logging()
        return int(_load(args.command).run(args) or 0)
    except ModuleNotFoundError as exc:
        name = next((a for a in argv if a in COMMANDS), None)
        top = (exc.name or "").split(".")[0]
        if name and COMMANDS[name].extra and top in _EXTRA_MODULES:
            print(_missing_extra_message(name, COMMANDS[name], exc), file=sys.stderr)
            return 3
        raise
    except KeyboardInterrupt:
        return 130


if __name__ == "__main__":
    sys.exit(main())
