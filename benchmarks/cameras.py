"""Camera estimation on the paper's training views of the shared scenes (``make bench-cameras``).

For each scene: the training views (3 LLFF/DTU, 8 Blender) are written as PNGs, their cameras
estimated from the pixels alone (``engine.sfm``), twice: with the focal length estimated from
a guess, and with the dataset's intrinsics given. Against the dataset's poses after a
similarity alignment: registered views, median and largest rotation error (degrees), mean
reprojection error, points, seconds, and the message when the estimation refused.

    python -m benchmarks.cameras [--data ROOT] [--scenes flower horns ...] [--match-side PX]

``--scale K`` enlarges the photos K times (bicubic; the intrinsics scaled with them) before
the estimate (``cameras-scale-K.json``): the seconds at another photo size, e.g. NeRF-synthetic's
original 800x800 from the shared 400x400 copy. The rotation errors stay comparable.

``--match-side PX`` has the learned attempt match the photos enlarged to PX pixels instead of
the matcher's default (the result goes to ``cameras-match-side-PX.json``): an estimate that
moves by degrees when only this changes is not pinned down by its photos, whatever its
orientation spread says.

``--train SCENE [--iterations N] [--given] [--seeds N ...] [--views N]`` instead trains the
scene with its preset (on N training views when ``--views`` is given), once per seed
(``--seeds``, default 0) for each run: from the dataset's training cameras, and from the
estimated ones (with the dataset's intrinsics when ``--given``) brought into the dataset's
frame by a similarity alignment: as the default recipe trains them (``estimated``: refined
during training when the estimate is uncertain, ``presets.pose_recipe``), held as estimated
(``fixed``) and refined (``refined``), and compares the held-out PSNR/SSIM/LPIPS on the
dataset's held-out views and protocol (DTU's object masks included). The cameras are estimated
once; the seed only changes the training. With more than one seed it also reports each run's
mean metrics over the seeds and, per seed and on average, each run's PSNR minus the dataset
run's. The alignment (``--align``) is fitted on the scene by default: the dataset's training
cameras see the estimate's triangulated matches where the estimated cameras see them, so that
the held-out cameras see the scene where the dataset has it; ``--align cameras`` fits the
training cameras' rotations and centres instead (the rotation errors of both are reported). The
results go to ``bench-results/cameras-train-SCENE-MODE.json`` (``-seeds-1-2`` appended unless
the seeds are just 0, so that runs of other seeds do not overwrite it).
"""

from __future__ import annotations

import argparse
import json
import tempfile
from pathlib import Path
from typing import Any

import numpy as np

from benchmarks.camera_photos import estimate_views, placed_views
from benchmarks.camera_training import (
    RUNS,
    format_summary,
    results_name,
    seed_summary,
    train_comparison,
)
from benchmarks.common import (
    SHARED_SCENES,
    format_table,
    machine_info,
    results_dir,
)
from benchmarks.quality import default_data_root
from sparsesplat.engine.commands.common import add_set_option

SCENES = SHARED_SCENES
"""Scene name -> folder under the shared data root."""
COLUMNS = ["scene", "size", "intrinsics", "views", "registered", "median_deg", "max_deg",
           "spread_deg", "reproj_px", "points", "seconds", "outcome"]  # fmt: skip


def measure(
    folder: Path, given: bool, threads: int, match_side: int | None = None, scale: int = 1
) -> dict[str, Any]:
    """One scene, one intrinsics mode: the figures of the module docstring; ``match_side``:
    the learned attempt's matching size (``camera_photos.attempts_matching_at``);
    ``scale``: the photos enlarged this many times (``camera_photos.write_training_photos``).
    A refusal's row has its seconds too: the time a user waits for it."""
    import time

    from sparsesplat.engine.datasets import load_scene
    from sparsesplat.engine.sfm import CameraEstimationError
    from sparsesplat.engine.sfm.align import align, rotation_errors_deg

    scene = load_scene(folder)
    views = scene.train
    cam = views[0].camera
    row: dict[str, Any] = {"views": len(views), "intrinsics": "given" if given else "estimated"}
    if match_side is not None:
        row["match_side"] = match_side
    if scale != 1:
        row["scale"] = scale
    row["size"] = f"{cam.width * scale}x{cam.height * scale}"
    with tempfile.TemporaryDirectory() as tmp:
        started = time.perf_counter()
        try:
            result = estimate_views(scene, given, threads, Path(tmp), match_side, scale)
        except CameraEstimationError as exc:
            seconds = time.perf_counter() - started  # the photos' writing included
            return {**row, "registered": 0, "seconds": seconds, "outcome": str(exc)}
    # The photos left out by name (no neighbour within reach) are scored as not registered;
    # the placed ones against their own dataset poses.
    placed = placed_views(scene, result)[0].train
    est = [np.linalg.inv(np.array(f.matrix)) for f in result.cameras.frames]
    ref = [v.camera.world_to_camera.double().numpy() for v in placed]
    errors = rotation_errors_deg(est, ref, align(est, ref))
    return {
        **row,
        "registered": len(est),
        "median_deg": float(np.median(errors)),
        "max_deg": float(np.max(errors)),
        "reproj_px": result.reprojection_error_px,
        "spread_deg": max((p.rotation_std_deg or 0.0) for p in result.photos),
        "points": len(result.points),
        "seconds": result.seconds,
        "focal_px": result.cameras.frames[0].fx,
        "focal_ref_px": float(cam.fx),
        "outcome": f"ok ({result.attempt})",
    }


def build_parser() -> argparse.ArgumentParser:
    """The command line of :func:`main`."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--data", type=Path, default=None, help="shared data root")
    parser.add_argument("--scenes", nargs="*", default=list(SCENES), choices=list(SCENES))
    parser.add_argument("--threads", type=int, default=2)
    parser.add_argument("--train", choices=list(SCENES), help="training comparison on SCENE")
    parser.add_argument("--iterations", type=int, default=None, help="with --train")
    parser.add_argument(
        "--given", action="store_true",
        help="with --train: estimate with the dataset's intrinsics held fixed",
    )  # fmt: skip
    parser.add_argument(
        "--runs", nargs="*", default=list(RUNS), choices=list(RUNS),
        help="with --train: which runs to make",
    )  # fmt: skip
    parser.add_argument(
        "--align", choices=("scene", "cameras"), default="scene",
        help="with --train: align the estimate by the scene's points or by the cameras",
    )  # fmt: skip
    parser.add_argument(
        "--seeds", nargs="+", type=int, default=[0], metavar="N",
        help="with --train: train each run once per seed (default 0)",
    )  # fmt: skip
    parser.add_argument(
        "--views", type=int, default=None, metavar="N",
        help="with --train: N training views (the loader's choice; default: the paper's)",
    )  # fmt: skip
    add_set_option(parser, "with --train: a training setting for every run (repeatable)")
    parser.add_argument(
        "--match-side", type=int, default=None, metavar="PX",
        help="without --train: the learned attempt matches photos enlarged to PX pixels "
        "(default: the matcher's own size)",
    )  # fmt: skip
    parser.add_argument(
        "--scale", type=int, default=1, metavar="K",
        help="without --train: enlarge the photos K times before the estimate (the seconds "
        "at a larger size; default 1)",
    )  # fmt: skip
    return parser


def _settings(parser: argparse.ArgumentParser, items: list[str]) -> dict[str, Any]:
    """``--set FIELD=JSON`` items as overrides by dotted name (a bad one is a usage error)."""
    from sparsesplat.engine.errors import ConfigError
    from sparsesplat.engine.train.config.overrides import parse_override

    settings: dict[str, Any] = {}
    for item in items:
        try:
            key, value = parse_override(item)
        except ConfigError as exc:
            parser.error(f"--set {exc}")
        settings[key] = value
    return settings


def main(argv: list[str] | None = None) -> int:
    """Measure every scene in both intrinsics modes; print a table, write JSON."""
    parser = build_parser()
    args = parser.parse_args(argv)
    if len(set(args.seeds)) != len(args.seeds):
        parser.error(f"--seeds: each seed once, got {args.seeds}")
    if args.train and args.match_side is not None:
        parser.error("--match-side goes without --train")
    if args.views is not None and (not args.train or args.views < 3):
        parser.error("--views takes a whole number >= 3, with --train")
    if args.scale < 1 or (args.train and args.scale != 1):
        parser.error("--scale takes a whole number >= 1, without --train")
    if args.set and not args.train:
        parser.error("--set goes with --train")
    settings = _settings(parser, args.set)
    root = args.data or default_data_root()
    if args.train:
        rows = train_comparison(
            root / SCENES[args.train], args.iterations, args.threads, args.given,
            tuple(args.runs), args.align, args.seeds, args.views, settings,
        )  # fmt: skip
        result: dict[str, Any] = {"machine": machine_info(), "seeds": args.seeds, "rows": rows}
        if settings:
            result["settings"] = settings
        if len(args.seeds) > 1:
            result["summary"] = seed_summary(rows)
            print(json.dumps({"summary": result["summary"]}), flush=True)
            print(format_summary(result["summary"]), flush=True)
        out = results_dir() / results_name(
            args.train, args.given, args.seeds, args.views, bool(settings)
        )
        out.parent.mkdir(parents=True, exist_ok=True)
        out.write_text(json.dumps(result, indent=1))
        print(f"written: {out}")
        return 0
    rows = []
    for name in args.scenes:
        for given in (False, True):
            row = {
                "scene": name,
                **measure(root / SCENES[name], given, args.threads, args.match_side, args.scale),
            }
            rows.append(row)
            print(json.dumps(row), flush=True)
    print(format_table(rows, COLUMNS))
    side = "" if args.match_side is None else f"-match-side-{args.match_side}"
    side += "" if args.scale == 1 else f"-scale-{args.scale}"
    out = results_dir() / f"cameras{side}.json"
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(json.dumps({"machine": machine_info(), "rows": rows}, indent=1))
    print(f"written: {out}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
