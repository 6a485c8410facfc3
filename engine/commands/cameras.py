"""``sparsesplat cameras PHOTOS -o cameras.json``: estimate the cameras of photos locally.

PHOTOS is a folder (every image in it, sorted by name) or image files in one folder. The
output is the one camera schema (docs/cameras.md) with the sparse points beside it
(``sparse_points.npz``), so the folder trains with ``sparsesplat train`` or uploads with
``sparsesplat submit``. No torch import at module level (the CLI imports this module to build
its parser).
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path
from typing import TYPE_CHECKING

if TYPE_CHECKING:
    from sparsesplat.api.cameras import Intrinsics


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """Register ``cameras PHOTOS... [-o FILE] [--intrinsics FX,FY,CX,CY] [--threads N]``."""
    parser.add_argument("photos", nargs="+", help="a folder of photos, or photo files")
    parser.add_argument(
        "-o",
        "--output",
        default=None,
        help="cameras file to write, in the photos' folder or above it (default: "
        "PHOTOS_FOLDER/cameras.json)",
    )
    parser.add_argument(
        "--intrinsics",
        default=None,
        help="shared pinhole intrinsics in pixels, 'fx,fy,cx,cy' or a JSON object, held "
        "fixed (default: estimated, starting from the EXIF focal length when present)",
    )
    parser.add_argument("--threads", type=int, default=2, help="CPU threads for COLMAP")
    parser.add_argument("--seed", type=int, default=0, help="random seed of COLMAP's RANSAC")


def _photos(items: list[str]) -> list[Path]:
    from sparsesplat.engine.images import list_images

    paths = [Path(p) for p in items]
    if len(paths) == 1 and paths[0].is_dir():
        return [p.resolve() for p in list_images(paths[0])]
    for path in paths:
        if not path.is_file():
            raise ValueError(f"{path}: not a file (give a folder of photos or photo files)")
    return [p.resolve() for p in paths]


def _intrinsics(text: str | None) -> Intrinsics | None:
    from pydantic import ValidationError

    from sparsesplat.api.cameras import Intrinsics

    if text is None:
        return None
    try:
        if text.lstrip().startswith("{"):
            return Intrinsics.model_validate_json(text)
        values = [float(v) for v in text.split(",")]
    except (ValueError, ValidationError) as exc:
        raise ValueError(f"--intrinsics: {exc}") from exc
    if len(values) != 4:
        raise ValueError(f"--intrinsics: 4 numbers fx,fy,cx,cy expected, got {len(values)}")
    try:
        return Intrinsics(fx=values[0], fy=values[1], cx=values[2], cy=values[3])
    except ValidationError as exc:
        raise ValueError(f"--intrinsics: {exc}") from exc


def run(args: argparse.Namespace) -> int:
    """Estimate and write; exit 2 with the reason when the photos cannot be registered."""
    from sparsesplat.engine.commands.common import fail
    from sparsesplat.engine.errors import EngineError
    from sparsesplat.engine.sfm import estimate_cameras
    from sparsesplat.engine.sfm.store import write_estimate

    try:
        photos = _photos(args.photos)
        intrinsics = _intrinsics(args.intrinsics)
        output = Path(args.output or photos[0].parent / "cameras.json").resolve()
        try:
            images = [p.relative_to(output.parent).as_posix() for p in photos]
        except ValueError:
            return fail(
                "cameras",
                f"{output}: write the cameras file in the photos' folder or above it (the "
                "frames name their images relative to it)",
            )
        estimate = estimate_cameras(photos, intrinsics, threads=args.threads, seed=args.seed)
    except (EngineError, ValueError) as exc:
        return fail("cameras", str(exc))
    output.parent.mkdir(parents=True, exist_ok=True)
    write_estimate(estimate, output, images)
    for photo in estimate.left_out:
        print(f"warning: {photo.reason}", file=sys.stderr)
    print(json.dumps({"cameras": str(output), **estimate.summary()}), file=sys.stdout)
    return 0
