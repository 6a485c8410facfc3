"""``sparsesplat submit FOLDER | FILES... [--wait]``: upload a scene as a training job.

A folder is read in any format the engine reads (LLFF, Blender, DTU, instant-ngp, an upload
folder with cameras.json) with the paper's training views; files are images listed by a
``--cameras`` cameras.json (frames matched by file name). A folder of photos alone, or files
without ``--cameras``, go up without cameras: the service estimates them first
(``--intrinsics`` holds shared ones fixed)."""

from __future__ import annotations

import argparse
import json
import posixpath
import sys
import warnings
from pathlib import Path
from typing import Any, get_args

from pydantic import ValidationError

from sparsesplat.api.cameras import Intrinsics
from sparsesplat.api.jobs import PresetName
from sparsesplat.client.commands.common import add_connection, client, dump, guarded, json_argument
from sparsesplat.client.commands.status import describe
from sparsesplat.client.errors import InvalidInput, JobFailed, JobWarning
from sparsesplat.client.photos import Photos, is_photo_folder, read_photos
from sparsesplat.client.scenes import Upload, read_scene


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """Scene, split, spec and waiting options."""
    parser.add_argument("paths", nargs="+", metavar="FOLDER|FILES", help="scene folder or images")
    parser.add_argument(
        "--cameras",
        help="cameras.json for FILES (frames matched by file name); without it the service "
        "estimates the cameras of the photos",
    )
    parser.add_argument(
        "--intrinsics",
        metavar="FX,FY,CX,CY",
        help="photos without cameras: shared pinhole intrinsics in pixels, held fixed",
    )
    scene = parser.add_argument_group("scene")
    scene.add_argument("--views", type=int, help="training views (default: the paper's)")
    scene.add_argument(
        "--test-views", default="all", help="held-out views to attach: all (default), N or 0"
    )
    scene.add_argument("--downscale", type=int, default=1, help="shrink images by N first")
    scene.add_argument("--format", choices=["folder", "llff", "blender", "dtu", "ngp"])
    spec = parser.add_argument_group("job spec")
    spec.add_argument("--spec", help="JobSpec as JSON text or a .json file")
    spec.add_argument(
        "--iterations", type=int, help="iterations to train (default: the preset's for the scene)"
    )
    spec.add_argument("--time-budget", type=float, metavar="S", help="training seconds instead")
    spec.add_argument("--preset", choices=list(get_args(PresetName)))
    spec.add_argument("--seed", type=int)
    parser.add_argument("--idempotency-key", help="reuse to make a retried submission safe")
    parser.add_argument("--wait", action="store_true", help="wait for the end, with progress")
    parser.add_argument("--timeout", type=float, metavar="S", help="give up waiting after S s")
    parser.add_argument("--no-progress", action="store_true", help="no progress bar")
    add_connection(parser)


def _spec(args: argparse.Namespace) -> dict[str, Any]:
    spec: dict[str, Any] = {}
    if args.spec:
        spec = json_argument(args.spec, "--spec", ("{",))
    for key, value in (
        ("iterations", args.iterations),
        ("time_budget_s", args.time_budget),
        ("preset", args.preset),
        ("seed", args.seed),
    ):
        if value is not None:
            spec[key] = value
    return spec


def _test_views(value: str) -> int | str:
    if value == "all":
        return "all"
    try:
        return int(value)
    except ValueError:
        raise InvalidInput(f"--test-views: 'all' or a number, got {value!r}") from None


def _intrinsics(text: str | None) -> Intrinsics | None:
    if text is None:
        return None
    try:
        fx, fy, cx, cy = (float(v) for v in text.split(","))
        return Intrinsics(fx=fx, fy=fy, cx=cx, cy=cy)
    except (ValueError, ValidationError) as exc:
        raise InvalidInput(f"--intrinsics {text!r}: four numbers FX,FY,CX,CY ({exc})") from exc


def _upload(args: argparse.Namespace) -> Upload | Photos:
    paths = [Path(p) for p in args.paths]
    missing = [str(p) for p in paths if not p.exists()]
    if missing:
        raise InvalidInput(f"{', '.join(missing)}: not found")
    if args.cameras is None and (len(paths) > 1 or is_photo_folder(paths[0])):
        return read_photos(paths, _intrinsics(args.intrinsics))
    if args.intrinsics is not None:
        raise InvalidInput("--intrinsics is for photos without cameras (no --cameras)")
    if len(paths) == 1 and paths[0].is_dir():
        test_views = _test_views(args.test_views)
        return read_scene(
            paths[0],
            views=args.views,
            test_views=test_views,  # type: ignore[arg-type]
            downscale=args.downscale,
            format=args.format,
        )
    if not args.cameras:
        raise InvalidInput(f"{paths[0]}: give a scene folder, photos, or --cameras cameras.json")
    folder_like = {posixpath.basename(p.name): p for p in paths}
    try:
        document = json.loads(Path(args.cameras).read_text())
    except (OSError, ValueError) as exc:
        raise InvalidInput(f"--cameras {args.cameras}: {exc}") from exc
    images: dict[str, bytes] = {}
    for frame in document.get("frames", []):
        name = posixpath.basename(str(frame.get("image", "")))
        if name not in folder_like:
            raise InvalidInput(f"cameras.json lists {name!r}, which is not among FILES")
        images[name] = folder_like[name].read_bytes()
        frame["image"] = name
    return Upload(document, images, source=str(args.cameras)).validate()


def run(args: argparse.Namespace) -> int:
    """Submit; print the job (id, or JSON); with --wait follow it to the end."""

    def body() -> int:
        upload = _upload(args)
        key = args.idempotency_key or "auto"
        with client(args) as c:
            job = c.submit(upload, _spec(args), idempotency_key=key)
            if not args.json:
                print(
                    f"submitted {job.id} ({upload.n_train} training + {upload.n_test} held-out "
                    f"views, {upload.source})",
                    file=sys.stderr,
                )
            if not args.wait:
                print(dump(job.info) if args.json else job.id)
                return 0
            try:
                with warnings.catch_warnings():
                    # The summary below lists the job's warnings; said once is enough.
                    warnings.simplefilter("ignore", JobWarning)
                    final = job.wait(args.timeout, progress=False if args.no_progress else None)
            except JobFailed as exc:
                print(dump(exc.job) if args.json else exc.job.id)
                if not args.json:
                    print(describe(exc.job), file=sys.stderr)
                raise
            print(dump(final) if args.json else final.id)
            if not args.json:
                # The end of the run on every stream, terminal or not: state, metrics, warnings
                # (stdout keeps only the id, for scripts).
                print(describe(final), file=sys.stderr)
            return 0

    return guarded(args, body)
