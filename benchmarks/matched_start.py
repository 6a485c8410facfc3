"""The matched start against the dataset (``engine.match.triangulate``, issue 55 item 2).

For each scene and matcher, the training views' matches (cached in ``bench-results/
match-cache``) are triangulated with the dataset's cameras and filtered (reprojection error,
triangulation angle). Reported: tracks and what each filter dropped, the kept points, their
reprojection error and triangulation angle, and against the dataset:

- forward-facing LLFF captures (flower, horns, beer_can): each point's depth in the training
  view that sees it against the plane-sweep start's depth there (``engine.priors`` plane sweep,
  where its confidence is at least 0.7, the dense start's cut): median relative difference and
  the fraction within 5 %;
- object scenes (mic, DTU): the fraction of points inside the object's bounds (the unit cube
  for NeRF-synthetic, the unit sphere for DTU's normalised frame) and inside the object's
  silhouette, widened by :data:`SILHOUETTE_SLACK_PX` (the reprojection error allowed), in
  every held-out view that frames it (alpha >= 0.5, DTU's masks).

    python -m benchmarks.matched_start [--scenes ...] [--methods ...]
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path
from typing import Any

import numpy as np

from benchmarks.common import RowLog, machine_info, results_dir
from benchmarks.matchers import (
    SCENES,
    add_match_arguments,
    load_views,
    parse_method,
    report,
    sift_matches,
)
from benchmarks.quality import default_data_root

COLUMNS = ["scene", "method", "tracks", "conflicts", "behind", "error", "angle", "kept",
           "err_med_px", "err_p90_px", "angle_med_deg", "views3", "depth_rel_med",
           "depth_within5", "inside_bounds", "inside_silhouettes", "tri_s"]  # fmt: skip
SILHOUETTE_SLACK_PX = 2
"""A point may project this far outside a held-out silhouette (pixels): the matched start
keeps points that reproject within 2 px, and thin parts are a few pixels wide."""
PLANE_SWEEP_CUT = 0.7
"""Plane-sweep confidence above which its depth is compared (the dense start's cut)."""


def _plane_sweep_check(scene: Any, start: Any, cache: Path) -> dict[str, float]:
    """Median |z / z_plane_sweep - 1| and the fraction within 5 % over the points' projections
    into every training view where the plane sweep is confident."""
    from sparsesplat.engine.match.geometry import PinholeArrays, project
    from sparsesplat.engine.priors import compute_priors

    priors = compute_priors(scene, "plane_sweep", cache_dir=cache)
    ratios = []
    for view, prior in zip(scene.train, priors, strict=True):
        cam = PinholeArrays.of(view.camera)
        uv, z = project(start.points.astype(np.float64), cam)
        h, w = prior.depth.shape
        ix, iy = np.floor(uv[:, 0]).astype(int), np.floor(uv[:, 1]).astype(int)
        inside = (z > 0) & (ix >= 0) & (ix < w) & (iy >= 0) & (iy < h)
        depth, conf = prior.depth.numpy(), prior.confidence.numpy()
        ok = np.zeros(len(z), bool)
        ok[inside] = conf[iy[inside], ix[inside]] >= PLANE_SWEEP_CUT
        ratios.append(z[ok] / depth[iy[ok], ix[ok]] - 1.0)
    rel = np.abs(np.concatenate(ratios)) if ratios else np.zeros(0)
    if not len(rel):
        return {}
    return {"depth_rel_med": float(np.median(rel)), "depth_within5": float(np.mean(rel < 0.05)),
            "depth_compared": len(rel)}  # fmt: skip


def _object_check(scene: Any, start: Any) -> dict[str, float]:
    """Fractions of points inside the bounds and inside every framing held-out silhouette."""
    import torch
    import torch.nn.functional as F

    from sparsesplat.engine.match.geometry import PinholeArrays, project

    pts = start.points.astype(np.float64)
    if scene.format == "dtu":
        bounds = np.linalg.norm(pts, axis=1) <= 1.0
    else:
        bounds = (np.abs(pts) <= 1.0).all(axis=1)
    inside = np.ones(len(pts), bool)
    for view in scene.test:
        sil = view.alpha.numpy() >= 0.5 if view.alpha is not None else None
        if sil is None and view.mask is not None:
            sil = view.mask.numpy().astype(bool)
        if sil is None:
            continue
        k = 2 * SILHOUETTE_SLACK_PX + 1
        grown = F.max_pool2d(torch.from_numpy(sil).float()[None, None], k, 1, k // 2)
        sil = grown[0, 0].numpy() > 0
        uv, z = project(pts, PinholeArrays.of(view.camera))
        h, w = sil.shape
        ix, iy = np.floor(uv[:, 0]).astype(int), np.floor(uv[:, 1]).astype(int)
        framed = (z > 0) & (ix >= 0) & (ix < w) & (iy >= 0) & (iy < h)
        inside[framed] &= sil[iy[framed], ix[framed]]
    return {"inside_bounds": float(bounds.mean()) if len(pts) else 0.0,
            "inside_silhouettes": float(inside.mean()) if len(pts) else 0.0}  # fmt: skip


def measure(
    name: str, folder: Path, method: str, cache: Path, settings: Any, object_masks: bool
) -> dict[str, Any]:
    """One scene, one matcher: the figures of the module docstring."""
    from sparsesplat.engine.match import cached_match, matched_start

    scene, photos, masks = load_views(folder, object_masks)
    if method == "sift":
        matches, _ = sift_matches(photos, 2)
    else:
        matches, _ = cached_match(photos, parse_method(method), cache, masks)
    settings_json = matches.settings.as_json() if method != "sift" else "sift"
    t0 = time.perf_counter()
    start = matched_start(matches, [v.camera for v in scene.train], photos, settings)
    seconds = time.perf_counter() - t0
    row: dict[str, Any] = {
        "scene": name,
        "method": method + ("+masks" if object_masks else ""),
        **start.counts,
        "tri_s": seconds,
        "settings": settings_json,
    }
    if len(start.points):
        row.update(
            err_med_px=float(np.median(start.errors)),
            err_p90_px=float(np.percentile(start.errors, 90)),
            angle_med_deg=float(np.median(start.angles)),
            views3=float(np.mean(start.views >= 3)),
            scale_med=float(np.median(start.scales)),
        )
        if scene.format in ("dtu", "blender"):
            row.update(_object_check(scene, start))
        else:
            row.update(_plane_sweep_check(scene, start, cache / "priors"))
    return row


def main(argv: list[str] | None = None) -> int:
    """Measure every scene x matcher; print a table, write JSON lines."""
    import torch

    from sparsesplat.engine.match import TriangulationSettings

    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    add_match_arguments(parser)
    parser.add_argument("--threads", type=int, default=1)
    parser.add_argument("--max-error", type=float, default=2.0, help="pixels")
    parser.add_argument("--min-angle", type=float, default=1.0, help="degrees")
    args = parser.parse_args(argv)
    if args.report:
        print(report(args.report, COLUMNS))
        return 0
    torch.set_num_threads(args.threads)
    root = args.data or default_data_root()
    cache = results_dir() / "match-cache"
    settings = TriangulationSettings(max_error_px=args.max_error, min_angle_deg=args.min_angle)
    out = args.out or results_dir() / "matched-start.jsonl"
    log = RowLog(out, {"machine": machine_info(), "settings": vars(args)}, COLUMNS)
    for name in args.scenes:
        for method in args.methods:
            log.add(measure(name, root / SCENES[name], method, cache, settings, args.object_masks))
    log.close()
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
