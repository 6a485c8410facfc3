"""``sparsesplat render CHECKPOINT --camera CAMERA.json -o OUT.png``: render a trained model.

The camera is the service's render camera, :class:`sparsesplat.api.cameras.PinholeCamera`:
``convention`` (opencv | opengl) and ``pose`` (camera_to_world | world_to_camera) are required,
plus ``matrix`` (4x4 rigid), ``fx, fy, cx, cy, width, height`` (docs/cameras.md). No torch
import at module level."""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path
from typing import Any, get_args

from sparsesplat.api.names import IMAGE_OUTPUT_SUFFIXES
from sparsesplat.api.renders import DEFAULT_RENDER_MODE, RenderMode, empty_renders
from sparsesplat.engine.commands.common import (
    CommandError,
    check_device,
    guarded,
    prepare_native,
)

IMAGE_SUFFIXES = {suffix: fmt.upper() for suffix, fmt in IMAGE_OUTPUT_SUFFIXES.items()}
"""Output suffix -> PIL format."""
MAX_RENDER_SIDE = 8192
"""Largest width or height a render may have (memory guard)."""

EPILOG = """camera JSON (a file, or the JSON itself inline):
  {"convention": "opencv" | "opengl", "pose": "camera_to_world" | "world_to_camera",
   "matrix": [[...4 numbers...], x4], "fx": ..., "fy": ..., "cx": ..., "cy": ...,
   "width": ..., "height": ...}
  opencv: +x right, +y down, +z forward (COLMAP); opengl: +x right, +y up, +z back (Blender).
  The matrix must be rigid (rotation + translation). See docs/cameras.md.
exit codes: 0 written, 2 bad input (checkpoint, camera, output path, device)."""


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """Register the render options."""
    parser.formatter_class = argparse.RawDescriptionHelpFormatter
    parser.epilog = EPILOG
    parser.add_argument("checkpoint", help="checkpoint.pt or a run folder holding one")
    parser.add_argument(
        "--camera", required=True, help="camera JSON file, or inline JSON (see below)"
    )
    parser.add_argument(
        "-o", "--output", required=True, help="output image (.png, .jpg or .webp; folders made)"
    )
    parser.add_argument("--depth", default=None, help="also write the depth as .npy here")
    parser.add_argument("--device", default="cpu", help="torch device (cpu, cuda)")
    parser.add_argument(
        "--mode",
        choices=get_args(RenderMode),
        default=DEFAULT_RENDER_MODE,
        help="neural: the model's own colours, exactly (default); baked: their degree-3 SH bake",
    )


def read_camera_spec(spec: str) -> Any:
    """The ``--camera`` value as a validated :class:`PinholeCamera`: inline JSON when it
    starts with '{', else a file path. CommandError says what is wrong (file not found, not
    JSON, which field)."""
    from pydantic import ValidationError

    from sparsesplat.api.cameras import PinholeCamera, describe_validation_error

    text = spec.strip()
    where = "--camera (inline JSON)"
    if not text.startswith("{"):
        path = Path(spec)
        where = f"--camera {spec}"
        if not path.is_file():
            if path.exists():
                raise CommandError(f"{where}: not a file")
            raise CommandError(f"{where}: file not found")
        try:
            text = path.read_text()
        except (OSError, UnicodeDecodeError) as exc:
            raise CommandError(f"{where}: cannot read ({exc})") from exc
    try:
        data = json.loads(text)
    except json.JSONDecodeError as exc:
        raise CommandError(f"{where}: not valid JSON ({exc})") from exc
    if not isinstance(data, dict):
        raise CommandError(
            f"{where}: expected one camera object {{...}}, got {type(data).__name__}"
        )
    try:
        camera = PinholeCamera.model_validate(data)
    except ValidationError as exc:
        raise CommandError(f"{where}: {describe_validation_error(exc, data)}") from exc
    if max(camera.width, camera.height) > MAX_RENDER_SIDE:
        raise CommandError(
            f"{where}: {camera.width}x{camera.height} is larger than {MAX_RENDER_SIDE} pixels "
            "on a side"
        )
    return camera


def _output_path(value: str, suffixes: dict[str, str], what: str) -> Path:
    path = Path(value)
    if path.suffix.lower() not in suffixes:
        got = f"'{path.suffix}'" if path.suffix else "no suffix"
        raise CommandError(
            f"{what} {value}: {got}; name the file with one of {', '.join(suffixes)}"
        )
    if path.exists() and path.is_dir():
        raise CommandError(f"{what} {value}: is a folder")
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise CommandError(f"{what} {value}: cannot create its folder ({exc})") from exc
    return path


def run(args: argparse.Namespace) -> int:
    """Render one view; 0 on success, 2 on a bad input (checkpoint, camera, path, device)."""
    return guarded("render", lambda: _run(args))


def _run(args: argparse.Namespace) -> int:
    import numpy as np

    from sparsesplat.engine.camera import Camera
    from sparsesplat.engine.model import load_model
    from sparsesplat.engine.model.encode import encode_image

    camera = read_camera_spec(args.camera)
    output = _output_path(args.output, IMAGE_SUFFIXES, "-o")
    depth_path = _output_path(args.depth, {".npy": "npy"}, "--depth") if args.depth else None
    device = check_device(args.device)
    prepare_native(device)
    model = load_model(args.checkpoint, device)
    out = model.render(Camera.from_wire(camera), mode=args.mode)
    coverage = float(out.alpha.mean())
    if empty_renders([coverage]):
        print(
            f"sparsesplat render: warning: the camera sees (almost) nothing of the model "
            f"({coverage:.1%} of pixels covered); check 'convention' and 'pose' (an OpenGL "
            "matrix read as OpenCV looks backwards) and that the camera faces the scene",
            file=sys.stderr,
        )
    # Pillow's default settings for each format (the service chooses faster ones for latency).
    fmt = IMAGE_OUTPUT_SUFFIXES[output.suffix.lower()]
    try:
        output.write_bytes(encode_image(out.image.permute(1, 2, 0).cpu().numpy(), fmt))
        if depth_path is not None:
            np.save(depth_path, out.depth[0].cpu().numpy())
    except OSError as exc:
        raise CommandError(f"cannot write the output ({exc})") from exc
    print(output)
    return 0
