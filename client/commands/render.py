"""``sparsesplat render MODEL|CHECKPOINT (--camera FILE | --orbit N | --view SPLIT:I) -o OUT``.

``MODEL`` is a model id on the service. When the argument is an existing local path (a
checkpoint or a run folder), the local engine command renders it instead (engine extra).

``--camera`` is a JSON file (or text) holding one camera in the service's schema
(``convention``, ``pose``, ``matrix``, ``fx fy cx cy width height``; see docs/cameras.md) or a
list of them (a camera path). ``OUT`` is an image (``.png .jpg .webp``, ``.npy`` for depth), a
folder (one numbered file per camera of a path) or a video (``.mp4 .gif``; video extra).
"""

from __future__ import annotations

import argparse
import importlib
import json
import sys
import warnings
from pathlib import Path
from typing import Any, get_args

from sparsesplat.api.cameras import PinholeCamera
from sparsesplat.api.names import VIDEO_SUFFIXES
from sparsesplat.api.renders import DEFAULT_RENDER_MODE, RenderMode, RenderOutput
from sparsesplat.client.commands.common import add_connection, client, guarded, json_argument
from sparsesplat.client.errors import InvalidInput, MissingExtra, RenderWarning, exit_code

LOCAL_COMMAND = "sparsesplat.engine.commands.render"
"""The engine's own render command, used for local checkpoints."""


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """Target, cameras, output."""
    parser.add_argument("target", metavar="MODEL|CHECKPOINT", help="model id or local checkpoint")
    which = parser.add_mutually_exclusive_group()
    which.add_argument("--camera", help="camera JSON file or text (one camera or a list)")
    which.add_argument(
        "--orbit", type=int, metavar="N", help="N cameras orbiting the model (service models)"
    )
    which.add_argument(
        "--view",
        metavar="SPLIT:I",
        help="the I-th uploaded camera of SPLIT, e.g. test:0 (service models: a local "
        "checkpoint does not hold its cameras; give it --camera)",
    )
    parser.add_argument("-o", "--output", required=True, help="image, folder or video file")
    parser.add_argument(
        "--kind",
        choices=["png", "jpeg", "webp", "depth16", "npy", "alpha"],
        help="what to render (default from the output suffix, else png)",
    )
    parser.add_argument("--downscale", type=int, default=1, help="divide the size by N")
    parser.add_argument(
        "--mode",
        choices=list(get_args(RenderMode)),
        default=DEFAULT_RENDER_MODE,
        help="colours: neural (the model's own, exact; default) or baked (the view-independent "
        "SH of the .ply export)",
    )
    parser.add_argument("--arc", type=float, default=360.0, help="--orbit arc in degrees")
    parser.add_argument("--fps", type=float, default=30.0, help="video frame rate")
    local = parser.add_argument_group("local checkpoint (engine extra)")
    local.add_argument("--depth", help="also write the depth as .npy here (local only)")
    local.add_argument("--device", help="torch device (local only)")
    add_connection(parser)


def _cameras(args: argparse.Namespace, model: Any) -> list[PinholeCamera | dict[str, Any]]:
    if args.camera:
        data = json_argument(args.camera, "--camera", ("{", "["))
        if isinstance(data, dict) and isinstance(data.get("path"), list):
            data = data["path"]
        items: list[Any] = data if isinstance(data, list) else [data]
        return items  # the server validates and names what is wrong
    if args.orbit:
        orbit: list[PinholeCamera | dict[str, Any]] = list(
            model.orbit(args.orbit, arc_deg=args.arc)
        )
        return orbit
    if args.view:
        split, _, index = args.view.partition(":")
        views = model.cameras(split or "test")
        try:
            number = int(index or 0)
            if number < 0:
                raise IndexError(number)
            return [views[number]]
        except (ValueError, IndexError):
            valid = (
                f"give {split}:0 to {split}:{len(views) - 1}" if views else "none to choose from"
            )
            raise InvalidInput(
                f"--view {args.view}: the model has {len(views)} {split} camera(s); {valid}"
            ) from None
    raise InvalidInput("give --camera FILE, --orbit N or --view SPLIT:I")


def _local(args: argparse.Namespace) -> int:
    """Hand a local checkpoint to the engine's render command."""
    if not args.camera:
        # A checkpoint holds the model, not the cameras it was trained from: --view and
        # --orbit need the service's record of the upload.
        given = "--view" if args.view else "--orbit" if args.orbit else "no camera"
        refused = InvalidInput(
            f"{given}: a local checkpoint renders from --camera FILE (one camera or a list, "
            "docs/cameras.md); --view and --orbit render a service model (give its id)"
        )
        print(f"error: {refused}", file=sys.stderr)
        return exit_code(refused)
    argv = [args.target, "-o", args.output]
    if args.camera:
        argv += ["--camera", args.camera]
    if args.depth:
        argv += ["--depth", args.depth]
    if args.device:
        argv += ["--device", args.device]
    argv += ["--mode", args.mode]
    try:
        module = importlib.import_module(LOCAL_COMMAND)
        parser = argparse.ArgumentParser(prog="sparsesplat render")
        module.add_arguments(parser)
        return int(module.run(parser.parse_args(argv)) or 0)
    except ModuleNotFoundError as exc:
        missing = MissingExtra(exc.name or "torch", "engine", "rendering a local checkpoint")
        print(f"sparsesplat render: {missing}", file=sys.stderr)
        return exit_code(missing)


def run(args: argparse.Namespace) -> int:
    """Render on the service (or locally for a checkpoint path); print what was written."""
    if Path(args.target).exists():
        return _local(args)

    def body() -> int:
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always", RenderWarning)
            code = render(args)
        for warning in caught:
            if issubclass(warning.category, RenderWarning):
                print(f"warning: {warning.message}", file=sys.stderr)
            else:
                warnings.warn_explicit(
                    warning.message, warning.category, warning.filename, warning.lineno
                )
        return code

    return guarded(args, body)


def render(args: argparse.Namespace) -> int:
    """Render on the service and print the files written."""
    out = Path(args.output)
    with client(args) as c:
        model = c.model(args.target)
        cameras = _cameras(args, model)
        options: dict[str, Any] = {"downscale": args.downscale, "mode": args.mode}
        if out.suffix.lower() in VIDEO_SUFFIXES:
            written = [model.video(cameras, out, fps=args.fps, **options)]
        elif len(cameras) > 1 or not out.suffix:
            kind: RenderOutput = args.kind or "png"
            written = model.render_path_to(cameras, out, kind, **options)
        else:
            written = [model.render_to(cameras[0], out, output=args.kind, **options)]
    if args.json:
        print(json.dumps({"model": args.target, "files": [str(p) for p in written]}))
    else:
        print("\n".join(str(p) for p in written))
    return 0
