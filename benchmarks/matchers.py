"""The learned matchers against the dataset's epipolar geometry (``engine.match``, issue 55).

For each scene, the paper's training views (3 LLFF/DTU, 8 Blender) are matched pair by pair
with each matcher; for every pair: the matches, the fraction of them within ``--px`` pixels of
the epipolar lines of the dataset's cameras (both ways: a match counts when each point lies
within the distance of the other's line), their precision (``median_px``: the median over
the matches of the larger of a match's two distances), and the seconds (extraction of the
photos plus the matching of every pair, divided by the pairs: the cost per pair of a full
set). SIFT is the baseline of ``engine.sfm`` (COLMAP's extraction, exhaustive matching and
two-view verification with the first attempt's settings; its verified matches are counted,
so its precision is that of the matches RANSAC kept, the learned ones' of all they return).

Background: images with alpha are matched inside alpha >= 0.5 (the Blender protocol); every
matcher drops keypoints on flat patches (``MatchSettings.min_texture``); ``--object-masks``
restricts DTU to its object masks.

    python -m benchmarks.matchers [--data ROOT] [--scenes flower ...]
        [--methods xfeat-lighterglue ... sift] [--threads 1 2]
"""

from __future__ import annotations

import argparse
import json
import os
import tempfile
import time
from pathlib import Path
from typing import Any

import numpy as np

from benchmarks.common import (
    SHARED_SCENES,
    RowLog,
    machine_info,
    results_dir,
)
from benchmarks.quality import default_data_root

SCENES = SHARED_SCENES
"""Scene name -> folder under the shared data root."""
DEFAULT_SCENES = ["flower", "horns", "mic", "dtu_scan24", "beer_can"]
"""Scenes measured without ``--scenes``."""
COLUMNS = ["scene", "method", "threads", "pairs", "matches", "inlier_frac", "inliers",
           "min_inliers", "median_px", "s_per_pair", "cpu_s_per_pair", "seconds",
           "load"]  # fmt: skip


def load_views(folder: Path, object_masks: bool) -> tuple[Any, list[np.ndarray], list[Any]]:
    """The scene, its training photos (uint8) and per-photo masks (alpha >= 0.5 where the
    images have alpha; the object masks with ``object_masks``; else None)."""
    from sparsesplat.engine.datasets import load_scene

    scene = load_scene(folder)
    photos = [(v.image.numpy() * 255 + 0.5).clip(0, 255).astype(np.uint8) for v in scene.train]
    masks: list[Any] = []
    for v in scene.train:
        if v.alpha is not None:
            masks.append(v.alpha.numpy() >= 0.5)
        elif object_masks and v.mask is not None:
            masks.append(v.mask.numpy().astype(bool))
        else:
            masks.append(None)
    return scene, photos, masks


def sift_matches(photos: list[np.ndarray], threads: int) -> tuple[Any, dict[str, int]]:
    """The SIFT baseline as a MatchSet of COLMAP's verified matches (engine.sfm's first
    attempt: its peak threshold, exhaustive matching, two-view verification with its minimum
    inlier count), and the raw match counts per pair."""
    from PIL import Image

    from sparsesplat.engine.match.result import MatchSet
    from sparsesplat.engine.match.settings import MatchSettings
    from sparsesplat.engine.sfm.attempts import ATTEMPTS
    from sparsesplat.engine.sfm.colmap import require_pycolmap

    pycolmap = require_pycolmap()
    attempt = ATTEMPTS[0]
    start = time.perf_counter()
    with tempfile.TemporaryDirectory() as tmp:
        root = Path(tmp)
        names = [f"{i:03d}.png" for i in range(len(photos))]
        for name, photo in zip(names, photos, strict=True):
            Image.fromarray(photo).save(root / name)
        database = root / "database.db"
        extraction = pycolmap.FeatureExtractionOptions()
        extraction.num_threads = threads
        extraction.sift.peak_threshold = attempt.peak_threshold
        reader = pycolmap.ImageReaderOptions()
        cpu = pycolmap.Device.cpu
        pycolmap.extract_features(
            database, root, names, pycolmap.CameraMode.SINGLE, reader, extraction, cpu
        )
        matching = pycolmap.FeatureMatchingOptions()
        matching.num_threads = threads
        verification = pycolmap.TwoViewGeometryOptions()
        verification.min_num_inliers = attempt.min_inliers
        pycolmap.match_exhaustive(
            database, matching_options=matching, verification_options=verification, device=cpu
        )
        db = pycolmap.Database.open(str(database))
        try:
            index = {im.image_id: names.index(im.name) for im in db.read_all_images()}
            keypoints = [np.zeros((0, 2), np.float32)] * len(names)
            for image_id, i in index.items():
                keypoints[i] = np.asarray(db.read_keypoints(image_id)[:, :2], np.float32)
            rows, raw = {}, {}
            pair_ids, geometries = db.read_two_view_geometries()
            for pair_id, geometry in zip(pair_ids, geometries, strict=True):
                a, b = pycolmap.pair_id_to_image_pair(pair_id)
                i, j = index[a], index[b]
                m = np.asarray(geometry.inlier_matches, np.int32).reshape(-1, 2)
                if i > j:
                    i, j, m = j, i, m[:, ::-1]
                rows[(i, j)] = np.ascontiguousarray(m)
                raw[f"{i}-{j}"] = len(db.read_matches(a, b))
        finally:
            db.close()
    seconds = time.perf_counter() - start
    result = MatchSet(
        keypoints=keypoints,
        matches=rows,
        scores={p: np.ones(len(r), np.float32) for p, r in rows.items()},
        sizes=[(p.shape[1], p.shape[0]) for p in photos],
        settings=MatchSettings(),
        seconds={"total": seconds},
    )
    return result, raw


def epipolar_errors(f: np.ndarray, xa: np.ndarray, xb: np.ndarray) -> np.ndarray:
    """Per match, the larger of its two distances to the dataset's epipolar lines (pixels):
    a match counts within ``--px`` when this is, and the median of it over a pair or a scene is
    how precisely the matcher places what it matches (``median_px``)."""
    from sparsesplat.engine.match.geometry import epipolar_distances

    da, db = epipolar_distances(f, xa, xb)
    return np.maximum(da, db)


def median_px(errors: np.ndarray) -> float | None:
    """The median of ``errors`` (None for no matches: a pair with none has no precision)."""
    return float(np.median(errors)) if len(errors) else None


def parse_method(spec: str) -> Any:
    """``METHOD[:key=value,...]`` (e.g. ``xfeat-lighterglue:max_keypoints=2048``) as
    MatchSettings."""
    from sparsesplat.engine.match import MatchSettings

    method, _, rest = spec.partition(":")
    options: dict[str, Any] = {}
    for item in filter(None, rest.split(",")):
        key, _, value = item.partition("=")
        options[key] = float(value) if "." in value else int(value)
    return MatchSettings(method=method, **options)


def measure(
    scene_name: str, folder: Path, method: str, threads: int, px: float, object_masks: bool
) -> dict[str, Any]:
    """One scene, one matcher (``sift`` or a :func:`parse_method` spec), one thread count:
    per pair and summed figures."""
    import torch

    from sparsesplat.engine.match import match_images
    from sparsesplat.engine.match.geometry import PinholeArrays, fundamental

    torch.set_num_threads(threads)
    scene, photos, masks = load_views(folder, object_masks)
    cams = [PinholeArrays.of(v.camera) for v in scene.train]
    raw: dict[str, int] = {}
    settings_json = "sift"
    if method != "sift":
        match_images(photos[:2], parse_method(method), masks[:2])  # load the networks
    # CPU seconds of this process (all its threads): far less sensitive than wall time to
    # other work on a shared machine; at one thread, the matcher's own cost.
    cpu = time.process_time()
    if method == "sift":
        result, raw = sift_matches(photos, threads)
    else:
        settings = parse_method(method)
        result = match_images(photos, settings, masks)
        settings_json = settings.as_json()
    cpu = time.process_time() - cpu
    n = len(photos)
    pairs: list[dict[str, Any]] = []
    errors: list[np.ndarray] = []
    for i in range(n):
        for j in range(i + 1, n):
            xa, xb = result.pair(i, j)
            error = epipolar_errors(fundamental(cams[i], cams[j]), xa, xb)
            errors.append(error)
            angle = _angle_deg(cams[i], cams[j])
            pairs.append({"pair": f"{i}-{j}", "matches": len(xa),
                          "inliers": int((error <= px).sum()), "median_px": median_px(error),
                          "angle_deg": round(angle, 1), "raw": raw.get(f"{i}-{j}")})  # fmt: skip
    matches = sum(p["matches"] for p in pairs)
    inliers = sum(p["inliers"] for p in pairs)
    seconds = result.seconds["total"]
    return {
        "scene": scene_name,
        "method": method + ("+masks" if object_masks else ""),
        "threads": threads,
        "views": n,
        "pairs": len(pairs),
        "matches": matches,
        "inliers": inliers,
        "inlier_frac": inliers / matches if matches else 0.0,
        "min_inliers": min(p["inliers"] for p in pairs),
        "median_px": median_px(np.concatenate(errors)),
        "seconds": seconds,
        "s_per_pair": seconds / len(pairs),
        "cpu_s_per_pair": cpu / len(pairs),
        # Other work on the machine slows every figure: the 1-minute load beside each row.
        "load": round(os.getloadavg()[0], 2),
        "settings": settings_json,
        "per_pair": pairs,
    }


def _angle_deg(a: Any, b: Any) -> float:
    """Angle between two cameras' optical axes (degrees)."""
    za, zb = a.world_to_camera[2, :3], b.world_to_camera[2, :3]
    return float(np.degrees(np.arccos(np.clip(za @ zb, -1.0, 1.0))))


def markdown(rows: list[dict[str, Any]], columns: list[str]) -> str:
    """Rows as a markdown table (floats to 3 significant digits)."""

    def cell(v: Any) -> str:
        if isinstance(v, float):
            return f"{v:.1f}" if abs(v) >= 10 else f"{v:.3g}"
        return "" if v is None else str(v)

    lines = ["| " + " | ".join(columns) + " |", "|" + "---|" * len(columns)]
    lines += ["| " + " | ".join(cell(r.get(c)) for c in columns) + " |" for r in rows]
    return "\n".join(lines)


def report(paths: list[Path], columns: list[str]) -> str:
    """The rows of JSON-lines result files as one markdown table."""
    rows = []
    for path in paths:
        for line in path.read_text().splitlines():
            row = json.loads(line)
            if "scene" in row:
                rows.append(row)
    return markdown(rows, columns)


def add_match_arguments(parser: argparse.ArgumentParser) -> None:
    """The options the match benches share: which scenes and matchers, DTU's object masks, the
    JSON-lines file, and ``--report`` (print earlier results instead of measuring)."""
    from sparsesplat.engine.match.settings import METHODS

    parser.add_argument("--data", type=Path, default=None, help="shared data root")
    parser.add_argument("--scenes", nargs="*", default=DEFAULT_SCENES, choices=list(SCENES))
    parser.add_argument("--methods", nargs="*", default=[*METHODS, "sift"])
    parser.add_argument("--object-masks", action="store_true", help="DTU: match on the object")
    parser.add_argument("--out", type=Path, default=None, help="JSON lines file")
    parser.add_argument("--report", type=Path, nargs="*", help="print results as markdown")


def main(argv: list[str] | None = None) -> int:
    """Measure every scene x matcher x thread count; print a table, write JSON lines."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    add_match_arguments(parser)
    parser.add_argument("--threads", nargs="*", type=int, default=[1, 2])
    parser.add_argument("--px", type=float, default=2.0, help="epipolar distance (pixels)")
    args = parser.parse_args(argv)
    if args.report:
        print(report(args.report, COLUMNS))
        return 0
    root = args.data or default_data_root()
    out = args.out or results_dir() / "matchers.jsonl"
    log = RowLog(out, {"machine": machine_info()}, COLUMNS)
    for threads in args.threads:
        for name in args.scenes:
            for method in args.methods:
                log.add(measure(name, root / SCENES[name], method, threads, args.px,
                                args.object_masks))  # fmt: skip
    log.close()
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
