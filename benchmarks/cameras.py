"""Camera estimation on the paper's training views of the shared scenes (``make bench-cameras``).

For each scene: the training views (3 LLFF/DTU, 8 Blender) are written as PNGs, their cameras
estimated from the pixels alone (``engine.sfm``), twice: with the focal length estimated from
a guess, and with the dataset's intrinsics given. Against the dataset's poses after a
similarity alignment: registered views, median and largest rotation error (degrees), mean
reprojection error, points, seconds, and the message when the estimation refused.

    python -m benchmarks.cameras [--data ROOT] [--scenes flower horns ...]

``--train SCENE --iterations N`` instead trains the scene twice with the same preset and
seed: from the dataset's cameras, and from the estimated ones with the held-out cameras
mapped into the estimated frame by the alignment (the estimated focal length for both), and
compares the held-out PSNR/SSIM/LPIPS.
"""

from __future__ import annotations

import argparse
import json
import tempfile
from pathlib import Path
from typing import Any

import numpy as np

from benchmarks.common import (
    SHARED_SCENES,
    format_table,
    machine_info,
    results_dir,
)
from benchmarks.quality import default_data_root

SCENES = SHARED_SCENES
"""Scene name -> folder under the shared data root."""
COLUMNS = ["scene", "intrinsics", "views", "registered", "median_deg", "max_deg",
           "reproj_px", "points", "seconds", "outcome"]  # fmt: skip


def measure(folder: Path, given: bool, threads: int) -> dict[str, Any]:
    """One scene, one intrinsics mode: the figures of the module docstring."""
    from PIL import Image

    from sparsesplat.api.cameras import Intrinsics
    from sparsesplat.engine.datasets import load_scene
    from sparsesplat.engine.sfm import CameraEstimationError, estimate_cameras
    from sparsesplat.engine.sfm.align import align, rotation_errors_deg

    scene = load_scene(folder)
    views = scene.train
    row: dict[str, Any] = {"views": len(views), "intrinsics": "given" if given else "estimated"}
    with tempfile.TemporaryDirectory() as tmp:
        paths = []
        for i, view in enumerate(views):
            pixels = (view.image.numpy() * 255 + 0.5).clip(0, 255).astype(np.uint8)
            paths.append(Path(tmp) / f"{i:03d}.png")
            Image.fromarray(pixels).save(paths[-1])
        cam = views[0].camera
        intrinsics = Intrinsics(fx=cam.fx, fy=cam.fy, cx=cam.cx, cy=cam.cy) if given else None
        try:
            result = estimate_cameras(paths, intrinsics, threads=threads)
        except CameraEstimationError as exc:
            return {**row, "registered": 0, "outcome": str(exc)}
    est = [np.linalg.inv(np.array(f.matrix)) for f in result.cameras.frames]
    ref = [v.camera.world_to_camera.double().numpy() for v in views]
    errors = rotation_errors_deg(est, ref, align(est, ref))
    return {
        **row,
        "registered": len(est),
        "median_deg": float(np.median(errors)),
        "max_deg": float(np.max(errors)),
        "reproj_px": result.reprojection_error_px,
        "points": len(result.points),
        "seconds": result.seconds,
        "focal_px": result.cameras.frames[0].fx,
        "focal_ref_px": float(cam.fx),
        "outcome": f"ok ({result.attempt})",
    }


def _write_estimated_folder(folder: Path, out: Path, threads: int) -> Path:
    """``out`` as an upload folder: the training views with estimated cameras, the held-out
    views at their dataset poses mapped by the similarity alignment."""
    from PIL import Image

    from sparsesplat.engine.datasets import load_scene
    from sparsesplat.engine.sfm import estimate_cameras
    from sparsesplat.engine.sfm.align import align
    from sparsesplat.engine.sfm.store import estimate_document, write_estimate

    scene = load_scene(folder)
    out.mkdir(parents=True, exist_ok=True)
    names = []
    for split, views in (("train", scene.train), ("test", scene.test)):
        for i, view in enumerate(views):
            pixels = (view.image.numpy() * 255 + 0.5).clip(0, 255).astype(np.uint8)
            names.append(f"{split}_{i:03d}.png")
            Image.fromarray(pixels).save(out / names[-1])
    train = [out / n for n in names if n.startswith("train")]
    result = estimate_cameras(train, threads=threads)
    est = [np.linalg.inv(np.array(f.matrix)) for f in result.cameras.frames]
    similarity = align(est, [v.camera.world_to_camera.double().numpy() for v in scene.train])
    write_estimate(result, out / "cameras.json")
    document = estimate_document(result)
    first = document["frames"][0]
    for i, view in enumerate(scene.test):
        w2c = similarity.map_world_to_camera(view.camera.world_to_camera.double().numpy())
        document["frames"].append(
            {**first, "image": f"test_{i:03d}.png", "matrix": np.linalg.inv(w2c).tolist(),
             "split": "test"}
        )  # fmt: skip
    (out / "cameras.json").write_text(json.dumps(document, indent=1))
    return out


def train_comparison(folder: Path, iterations: int, threads: int) -> list[dict[str, Any]]:
    """Held-out metrics of the same run from the dataset's and the estimated cameras."""
    import torch

    from sparsesplat.engine.datasets import load_scene
    from sparsesplat.engine.train.run import RunSpec, build_run

    torch.set_num_threads(threads)
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        estimated = _write_estimated_folder(folder, Path(tmp) / "estimated", threads)
        for cameras, path in (("dataset", folder), ("estimated", estimated)):
            scene = load_scene(path)
            name = {"llff": "llff", "dtu": "dtu", "blender": "blender"}.get(scene.format, "llff")
            # The one run recipe (the CLI's and the service's), with the preset named.
            spec = RunSpec(name, {"seed": 0, "threads": threads}, iterations)
            result = build_run(spec, scene, out_dir=Path(tmp) / cameras).trainer.run()
            metrics = result.metrics
            row = {"cameras": cameras, "preset": name, "iterations": iterations,
                   "test_views": len(scene.test), "seconds": result.seconds,
                   **{k: metrics.get(k) for k in ("psnr", "ssim", "lpips")}}  # fmt: skip
            rows.append(row)
            print(json.dumps(row), flush=True)
    return rows


def main(argv: list[str] | None = None) -> int:
    """Measure every scene in both intrinsics modes; print a table, write JSON."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--data", type=Path, default=None, help="shared data root")
    parser.add_argument("--scenes", nargs="*", default=list(SCENES), choices=list(SCENES))
    parser.add_argument("--threads", type=int, default=2)
    parser.add_argument("--train", choices=list(SCENES), help="training comparison on SCENE")
    parser.add_argument("--iterations", type=int, default=None, help="with --train")
    args = parser.parse_args(argv)
    root = args.data or default_data_root()
    if args.train:
        rows = train_comparison(root / SCENES[args.train], args.iterations, args.threads)
        out = results_dir() / f"cameras-train-{args.train}.json"
        out.parent.mkdir(parents=True, exist_ok=True)
        out.write_text(json.dumps({"machine": machine_info(), "rows": rows}, indent=1))
        print(f"written: {out}")
        return 0
    rows = []
    for name in args.scenes:
        for given in (False, True):
            row = {"scene": name, **measure(root / SCENES[name], given, args.threads)}
            rows.append(row)
            print(json.dumps(row), flush=True)
    print(format_table(rows, COLUMNS))
    out = results_dir() / "cameras.json"
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(json.dumps({"machine": machine_info(), "rows": rows}, indent=1))
    print(f"written: {out}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
