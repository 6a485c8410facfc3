"""``make bench-per-view``: where on the held-out views two variants of bench-quality differ.

A scene mean hides which views a variant wins or loses. This reads bench-quality result files,
takes each run's per-view held-out PSNR (``metrics.json`` ``views``, written by the trainer
since it keeps them; an older run is re-scored from its ``checkpoint.pt``), averages each view
over the seeds of a variant, and prints one row per held-out view with the angle between its
optical axis and the nearest training camera's (the wider the angle, the more the view
extrapolates from the three photos).

    make bench-per-view BENCH_ARGS="bench-results/quality.json --scenes dtu_scan24 \\
        --variants full,no_depth"

Writes the table to bench-results/per_view.json. Re-scoring needs the runs' folders
(bench-quality's ``--runs-dir``) and renders on the CPU: seconds per run at 400x300.
"""

from __future__ import annotations

import argparse
import json
import math
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from benchmarks.common import write_results
from sparsesplat.api.names import ARTIFACT_FILES

PSNR_KEY = "psnr"


def axis_angle_deg(a: Any, b: Any) -> float:
    """Angle in degrees between two cameras' optical axes (their +z in world axes)."""
    za = a.camera_to_world[:3, 2].double()
    zb = b.camera_to_world[:3, 2].double()
    cos = float((za @ zb) / (za.norm() * zb.norm()))
    return math.degrees(math.acos(max(-1.0, min(1.0, cos))))


def nearest_training_angles(scene: Any) -> dict[str, float]:
    """Per held-out view name, the smallest optical-axis angle to a training camera."""
    return {
        view.name: min(axis_angle_deg(view.camera, t.camera) for t in scene.train)
        for view in scene.test
    }


def best_gain(render: Any, truth: Any, mask: Any | None) -> np.ndarray:
    """The per-channel gain g minimising the squared error of ``render * g`` against ``truth``
    (float64 least squares, over the pixels where ``mask`` is 1 when given, else all): the
    most a brightness model of the held-out view could correct. It reads the held-out photo,
    so it is a diagnostic of how much of a view's error is brightness, never a score."""
    a = np.asarray(render, dtype=np.float64)[..., :3]
    b = np.asarray(truth, dtype=np.float64)[..., :3]
    if mask is not None:
        m = np.asarray(mask, dtype=np.float64)
        keep = (m[..., 0] if m.ndim == 3 else m) == 1.0
        a, b = a[keep], b[keep]
    a, b = a.reshape(-1, 3), b.reshape(-1, 3)
    energy = (a * a).sum(axis=0)
    # A channel the render leaves black has no gain to fit: keep it as it is.
    return np.where(energy > 0, (a * b).sum(axis=0) / np.maximum(energy, 1e-300), 1.0)


def view_psnr_of_run(out_dir: Path, scene: Any, gain: bool = False) -> dict[str, float]:
    """Per held-out view PSNR of one bench-quality run: from its ``metrics.json`` when the
    trainer wrote ``views`` there, else by rendering its checkpoint (same evaluator). With
    ``gain`` the checkpoint is always rendered and each render is first multiplied by its
    view's :func:`best_gain` (clipped to [0, 1])."""
    metrics_path = out_dir / ARTIFACT_FILES["metrics"]
    if metrics_path.is_file() and not gain:
        views = json.loads(metrics_path.read_text()).get("views")
        if views:
            return {name: float(scores[PSNR_KEY]) for name, scores in views.items()}
    checkpoint = out_dir / ARTIFACT_FILES["checkpoint"]
    if not checkpoint.is_file():
        raise SystemExit(f"bench-per-view: {out_dir}: neither per-view metrics nor a checkpoint")
    import torch

    from sparsesplat.engine.metrics.evaluate import PSNR_CEILING, Evaluator
    from sparsesplat.engine.model import load_model

    model = load_model(checkpoint)
    evaluator = Evaluator(lpips_mode="off", psnr_ceiling=PSNR_CEILING)
    out = {}
    with torch.no_grad():
        for view in scene.test:
            image = model.render(view.camera).image.permute(1, 2, 0)
            if gain:
                rgb = image.clamp(0, 1).double().numpy()
                mask = None if view.mask is None else view.mask.numpy()
                image = np.clip(rgb * best_gain(rgb, view.image.numpy(), mask), 0.0, 1.0)
            value = evaluator.score_view(image, view.image, view.mask)[PSNR_KEY]
            assert value is not None  # PSNR is computed for every view
            out[view.name] = value
    return out


def per_view_rows(
    results: list[dict[str, Any]], scene: Any, variants: Sequence[str], gain: bool = False
) -> list[dict[str, Any]]:
    """One row per held-out view of ``scene``: its angle to the nearest training camera and,
    per variant, the mean PSNR over that variant's seeds (plus ``<variant>_seeds``); with
    ``gain`` also ``<variant>_gain``, the mean PSNR after each render's :func:`best_gain`."""
    angles = nearest_training_angles(scene)
    rows: list[dict[str, Any]] = [{"view": name, "angle_deg": a} for name, a in angles.items()]
    for variant in variants:
        runs = [
            r
            for r in results
            if r.get("scene") == scene.name and r.get("variant") == variant and not r.get("error")
        ]
        if not runs:
            raise SystemExit(f"bench-per-view: no {variant!r} run of {scene.name} in the results")
        columns = {variant: False, f"{variant}_gain": True} if gain else {variant: False}
        for column, gained in columns.items():
            per_run = [view_psnr_of_run(Path(r["out_dir"]), scene, gained) for r in runs]
            for row in rows:
                values = [p[row["view"]] for p in per_run]
                row[column] = sum(values) / len(values)
        rows[0][f"{variant}_seeds"] = ",".join(str(r.get("seed", 0)) for r in runs)
    return rows


def main(argv: Sequence[str] | None = None) -> int:
    """Entry point of ``python -m benchmarks.per_view``."""
    parser = argparse.ArgumentParser(prog="bench-per-view", description=__doc__.split("\n")[0])
    parser.add_argument("results", nargs="+", type=Path, help="bench-quality result files")
    parser.add_argument("--scenes", required=True, help="comma list of scene names")
    parser.add_argument("--variants", required=True, help="comma list of variants to compare")
    parser.add_argument("--threads", type=int, default=None, help="torch CPU threads")
    parser.add_argument(
        "--gain",
        action="store_true",
        help="also the PSNR after each held-out render's best per-channel gain against its "
        "photo (renders the checkpoints; a diagnostic of how much error is brightness)",
    )
    args = parser.parse_args(argv)

    import torch

    from benchmarks.quality import load_rows
    from sparsesplat.engine.datasets import load_scene

    if args.threads:
        torch.set_num_threads(args.threads)
    results = [row for path in args.results for row in load_rows(path)]
    variants = [v.strip() for v in args.variants.split(",") if v.strip()]
    table: list[dict[str, Any]] = []
    for name in [s.strip() for s in args.scenes.split(",") if s.strip()]:
        paths = {r["path"] for r in results if r.get("scene") == name and r.get("path")}
        if not paths:
            raise SystemExit(f"bench-per-view: no run of scene {name!r} in the results")
        # The paper split, as bench-quality trains it (its default --views).
        scene = load_scene(sorted(paths)[0])
        for row in per_view_rows(results, scene, variants, args.gain):
            table.append({"scene": scene.name, **row})
    columns = [c for v in variants for c in ((v, f"{v}_gain") if args.gain else (v,))]
    write_results("per_view", table, ["scene", "view", "angle_deg", *columns])
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
