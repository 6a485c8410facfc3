"""Shared by the local commands (train, render, scene): exit codes, device checks, the native
extension notice, JSON output. No torch import at module level."""

from __future__ import annotations

import argparse
import json
import logging
import os
import sys
import threading
from collections.abc import Callable
from typing import Any

log = logging.getLogger(__name__)

EXIT_BAD_INPUT = 2
"""Exit code for input the user can fix (scene, camera, option, checkpoint)."""
EXIT_FAILED = 1
"""Exit code for a run that failed on valid input (divergence, collapse, a build failure)."""

NATIVE_NOTICE_AFTER_S = 2.0
"""Say that the native extensions are being compiled when loading them takes longer."""


class CommandError(Exception):
    """A command-line input is wrong; the message says what and how to fix it."""


def fail(command: str, message: str, code: int = EXIT_BAD_INPUT) -> int:
    """Print ``sparsesplat COMMAND: message`` on stderr and return ``code``."""
    print(f"sparsesplat {command}: {message}", file=sys.stderr, flush=True)
    return code


def exit_code(exc: BaseException) -> int:
    """:data:`EXIT_FAILED` for runs that failed on valid input (training diverged, model
    collapsed, rasterizer build failures), :data:`EXIT_BAD_INPUT` for everything else."""
    from sparsesplat.engine.errors import RasterError, TrainingDiverged
    from sparsesplat.engine.train import ModelCollapsed

    failed = (TrainingDiverged, RasterError, ModelCollapsed)
    return EXIT_FAILED if isinstance(exc, failed) else EXIT_BAD_INPUT


def guarded(command: str, body: Callable[[], int]) -> int:
    """Run ``body``; a :class:`CommandError` or a typed engine error becomes ``sparsesplat
    COMMAND: message`` on stderr and its exit code (:func:`exit_code`)."""
    from sparsesplat.engine.errors import EngineError

    try:
        return body()
    except CommandError as exc:
        return fail(command, str(exc))
    except EngineError as exc:
        return fail(command, str(exc), exit_code(exc))


def check_device(device: str) -> str:
    """Validate ``--device``: a torch device name that this torch build and machine can use.
    Raises :class:`CommandError` saying why not (e.g. CUDA requested on a CPU-only torch)."""
    import torch

    try:
        dev = torch.device(device)
    except (RuntimeError, ValueError) as exc:
        raise CommandError(
            f"--device {device!r} is not a torch device (cpu, cuda, cuda:1)"
        ) from exc
    if dev.type == "cuda":
        if torch.version.cuda is None:
            raise CommandError(
                f"--device {device}: this torch build has no CUDA support (torch "
                f"{torch.__version__}); use --device cpu, or install a CUDA build of torch "
                "and gsplat (README, 'Install only what you need')"
            )
        if not torch.cuda.is_available():
            raise CommandError(f"--device {device}: no CUDA GPU is visible; use --device cpu")
        if dev.index is not None and dev.index >= torch.cuda.device_count():
            raise CommandError(
                f"--device {device}: only {torch.cuda.device_count()} CUDA device(s) visible"
            )
    elif dev.type != "cpu":
        raise CommandError(f"--device {device}: only cpu and cuda are supported")
    return str(dev)


def prepare_native(device: str, color: bool = True, training: bool = False) -> None:
    """Load (building on first use) the native CPU extensions before the work starts, saying
    on stderr what is happening when it takes a while (a first build takes minutes).
    ``training`` adds the fused photometric loss, which only training uses."""
    if not device.startswith("cpu"):
        return
    from sparsesplat.engine.kernels import load_kernels

    done = threading.Event()
    where = os.environ.get("TORCH_EXTENSIONS_DIR") or "~/.cache/torch_extensions"

    def notice() -> None:
        if not done.wait(NATIVE_NOTICE_AFTER_S):
            print(
                "sparsesplat: building the native CPU extensions: once after install or "
                f"update, a few minutes on 2 cores (`sparsesplat build` does it ahead); "
                f"cached under {where}",
                file=sys.stderr,
                flush=True,
            )

    log.info("loading native CPU extensions (cache: %s)", where)
    thread = threading.Thread(target=notice, daemon=True)
    thread.start()
    try:
        load_kernels(color=color, training=training)
    finally:
        done.set()
        thread.join()


def json_line(obj: dict[str, Any]) -> str:
    """One JSON object on one line; non-finite floats become null (valid JSON)."""
    from sparsesplat.engine.train.loop.recorder import json_safe

    return json.dumps(json_safe(obj), allow_nan=False, default=str)


def add_set_option(parser: argparse.ArgumentParser, help: str) -> None:
    """The repeatable ``--set FIELD=JSON`` option: TrainConfig fields by their dotted names,
    each read by :func:`~sparsesplat.engine.train.config.overrides.parse_override` from the
    list ``args.set``; ``help`` says what the overrides apply to."""
    parser.add_argument("--set", action="append", default=[], metavar="FIELD=JSON", help=help)
