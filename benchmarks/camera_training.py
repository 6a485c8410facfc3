"""The training comparison of ``bench-cameras --train``: the same run from the dataset's
training cameras and from the estimated ones, scored on the dataset's held-out views (see
``benchmarks/cameras.py`` for the command line)."""

from __future__ import annotations

import json
import tempfile
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from benchmarks.camera_photos import estimate_views, placed_views

ALIGN_MAX_ERROR_PX = 2.0
"""A matched point takes part in the scene alignment when it reprojects within this many
pixels in every estimated photo (the matched start's own filter)..."""
ALIGN_MIN_ANGLE_DEG = 1.0
"""... and was seen under at least this triangulation angle (its depth is defined)."""


def scene_alignment(
    photos: list[Any], ref: list[Any], est: list[Any], matches: Any = None
) -> tuple[Any, int]:
    """The similarity taking the dataset's frame to the estimate's, fitted on what the photos
    show: the training photos' matches (``matches``, or the engine matcher's defaults)
    triangulated with the estimated cameras ``est``, and the similarity under which the
    dataset's cameras ``ref`` see those points where the estimated ones do
    (``engine.sfm.align.align_reprojection``; both lists of ``PinholeArrays``, one per photo).
    Also returns how many points it used."""
    from sparsesplat.engine.match.matcher import match_images
    from sparsesplat.engine.match.tracks import build_tracks
    from sparsesplat.engine.match.triangulate import (
        dlt,
        refine,
        reprojection,
        triangulation_angles,
    )
    from sparsesplat.engine.sfm.align import align_reprojection

    matches = matches if matches is not None else match_images(photos)
    tracks = build_tracks(matches)
    x, usable = dlt(tracks, est)
    x[usable] = refine(x, tracks, est, 5)[usable]
    x[~usable] = 0.0
    err, z = reprojection(x, tracks, est)
    bad = ~(np.isfinite(err) & (err <= ALIGN_MAX_ERROR_PX) & (z > 0))
    usable[tracks.track[bad]] = False
    usable &= triangulation_angles(x, tracks, est) >= ALIGN_MIN_ANGLE_DEG
    sim = align_reprojection(
        x[usable],
        [c.world_to_camera for c in est],
        [c.world_to_camera for c in ref],
        [c.K for c in est],
        [c.K for c in ref],
    )
    return sim, int(usable.sum())


def _pinholes(
    w2cs: list[np.ndarray], intrinsics: Sequence[tuple[float, float, float, float]]
) -> list[Any]:
    """``PinholeArrays`` from world-to-camera matrices and (fx, fy, cx, cy) per camera."""
    from sparsesplat.engine.match.geometry import PinholeArrays

    out = []
    for w2c, (fx, fy, cx, cy) in zip(w2cs, intrinsics, strict=True):
        k = np.array([[fx, 0.0, cx], [0.0, fy, cy], [0.0, 0.0, 1.0]])
        out.append(PinholeArrays(k, np.asarray(w2c, dtype=np.float64)))
    return out


def with_estimated_cameras(
    scene: Any, estimate: Any, by: str = "scene", matches: Any = None
) -> tuple[Any, dict[str, float]]:
    """``scene`` with its training cameras replaced by ``estimate``'s, brought into the
    dataset's frame by a similarity alignment, and the estimate's sparse points likewise;
    everything else (held-out cameras, masks, bounds, format) is the dataset's. A run on it
    differs from one on ``scene`` only by the estimation's errors: the poses' residual after
    the alignment and, unless given, the intrinsics; and, as from an uploaded estimate, the
    estimate's orientation uncertainty (``Scene.pose_std_deg``), which decides whether the
    default recipe refines the poses.

    ``by``: ``"scene"`` (:func:`scene_alignment`, what the held-out views see: the object where
    the dataset has it) or ``"cameras"`` (``engine.sfm.align.align``: the rotations and
    centres of the training cameras). Also returns the rotation errors (median and largest,
    degrees) under the chosen alignment, the same under the camera alignment
    (``cameras_median_deg``, ``cameras_max_deg``), the points the scene alignment used, and
    the estimated focal length."""
    import dataclasses

    import torch

    from sparsesplat.engine.sfm.align import align, rotation_errors_deg

    est = [np.linalg.inv(np.array(f.matrix)) for f in estimate.cameras.frames]
    ref = [v.camera.world_to_camera.double().numpy() for v in scene.train]
    by_cameras = align(est, ref)
    figures: dict[str, float] = {}
    if by == "scene":
        from sparsesplat.engine.match.geometry import PinholeArrays

        est_k = [(f.fx, f.fy, f.cx, f.cy) for f in estimate.cameras.frames]
        ref_cams = [PinholeArrays.of(v.camera) for v in scene.train]
        sim, used = scene_alignment(
            [v.image for v in scene.train], ref_cams, _pinholes(est, est_k), matches
        )
        figures["alignment_points"] = used
    elif by == "cameras":
        sim = by_cameras
    else:
        raise ValueError(f"alignment by 'scene' or 'cameras', got {by!r}")
    errors = rotation_errors_deg(est, ref, sim)
    cam_errors = rotation_errors_deg(est, ref, by_cameras)
    back = sim.inverse()  # the estimated frame -> the dataset's
    train = []
    for view, w2c_est, frame in zip(scene.train, est, estimate.cameras.frames, strict=True):
        camera = _posed(view.camera, back.map_world_to_camera(w2c_est),
                        (frame.fx, frame.fy, frame.cx, frame.cy))  # fmt: skip
        train.append(dataclasses.replace(view, camera=camera))
    points = back.map_points(estimate.points.astype(np.float64))
    sparse = (torch.from_numpy(points).float(), torch.from_numpy(estimate.colours).float())
    figures.update(
        median_deg=float(np.median(errors)), max_deg=float(np.max(errors)),
        cameras_median_deg=float(np.median(cam_errors)), cameras_max_deg=float(np.max(cam_errors)),
        focal_px=float(estimate.cameras.frames[0].fx),
    )  # fmt: skip
    spreads = [
        f.rotation_std_deg for f in estimate.cameras.frames if f.rotation_std_deg is not None
    ]
    pose_std = max(spreads) if spreads else None  # as the folder loader reads cameras.json
    if pose_std is not None:
        figures["pose_std_deg"] = pose_std
    return dataclasses.replace(
        scene, train=train, sparse_points=sparse, pose_std_deg=pose_std
    ), figures


RUNS = ("dataset", "estimated", "fixed", "refined")
"""The runs of a training comparison: from the dataset's cameras; from the estimated ones as the
default recipe trains them (their poses refined when the estimate is uncertain,
``presets.pose_recipe``); from the estimated ones held as estimated (``poses.enabled`` off); and
refined during training (``poses.enabled`` on)."""


def train_comparison(
    folder: Path,
    iterations: int | None,
    threads: int,
    given: bool,
    runs: tuple[str, ...] = RUNS,
    by: str = "scene",
    seeds: Sequence[int] = (0,),
    views: int | None = None,
    settings: dict[str, Any] | None = None,
) -> list[dict[str, Any]]:
    """Held-out metrics of the same run (the scene's preset, once per seed of ``seeds``; each
    row names its ``seed``) from the dataset's and from the estimated training cameras
    (:func:`with_estimated_cameras`, estimated once for all seeds), the latter also with the
    cameras refined during training, scored on the dataset's held-out views and protocol
    (DTU's object masks included). A refined run is scored twice: at the held-out cameras as
    the dataset gives them (its first camera fixed the frame), and at those cameras mapped by
    the similarity that aligns its refined training cameras to the dataset's (``realigned``).
    ``by``: how the estimate is aligned to the dataset (:func:`with_estimated_cameras`);
    ``views``: training views (the dataset loader's choice, e.g. DTU's paper list in order;
    None: the paper's count); ``settings``: training settings by dotted name for every run
    (``--set``; the run's own ``poses.enabled``, seed and threads applied after them)."""
    import torch

    from sparsesplat.engine.datasets import load_scene
    from sparsesplat.engine.train.run import RunSpec, build_run

    torch.set_num_threads(threads)
    dataset = load_scene(folder, views)
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        estimate = estimate_views(dataset, given, threads, Path(tmp))
        dataset, placed = placed_views(dataset, estimate)
        estimated, figures = with_estimated_cameras(dataset, estimate, by)
        print(json.dumps({"estimate": figures, "placed": placed}), flush=True)
        for seed in seeds:
            for run in runs:
                scene = dataset if run == "dataset" else estimated
                overrides: dict[str, Any] = {**(settings or {}), "seed": seed, "threads": threads}
                if run in ("fixed", "refined"):
                    overrides["poses.enabled"] = run == "refined"
                # The one run recipe (the CLI's and the service's), its preset from the format.
                spec = RunSpec(None, overrides, iterations)
                out_dir = Path(tmp) / f"{run}-seed{seed}"
                trainer = build_run(spec, scene, out_dir=out_dir).trainer
                result = trainer.run()
                metrics = result.metrics
                row = {"cameras": run, "seed": seed,
                       "intrinsics": "given" if given else "estimated",
                       "preset": metrics.get("preset"), "iterations": metrics.get("iterations"),
                       "train_views": len(scene.train), "test_views": len(scene.test),
                       "seconds": result.seconds,
                       **{k: metrics.get(k) for k in METRICS},
                       **(figures if run != "dataset" else {})}  # fmt: skip
                if trainer.poses is not None:  # refined: scored at its own cameras too
                    row["pose_refinement"] = metrics.get("pose_refinement")
                    row["refined_deg"] = refined_errors(trainer, dataset, by)
                    row["realigned"] = realigned_metrics(trainer, dataset, by)
                rows.append(row)
                print(json.dumps(row), flush=True)
    return rows


METRICS = ("psnr", "ssim", "lpips")
"""The held-out metrics of a training comparison's rows."""


def _mean(values: Sequence[float | None]) -> float | None:
    """The mean of ``values``, or None when there are none or one is missing."""
    if not values or any(v is None for v in values):
        return None
    return float(np.mean([float(v) for v in values if v is not None]))


def _scored_psnr(row: dict[str, Any]) -> float | None:
    """A row's held-out PSNR in its model's own frame: ``realigned`` where its poses were
    refined, else as scored."""
    realigned = row.get("realigned")
    return realigned.get("psnr") if realigned else row.get("psnr")


def seed_summary(rows: Sequence[dict[str, Any]]) -> dict[str, Any]:
    """Over the seeds of :func:`train_comparison`'s ``rows``: per run kind (``means``), the
    seeds and the mean of each held-out metric; and per run kind other than ``dataset``
    (``psnr_gap``, when there are dataset rows), its PSNR minus the dataset run's of the same
    seed, per seed (``per_seed``, seed -> dB, only the seeds both ran) and their ``mean``. A
    run whose poses were refined counts its ``realigned`` PSNR (scored at the held-out cameras
    placed by its own refined training cameras, the frame its model is in)."""
    by_run: dict[str, dict[int, dict[str, Any]]] = {}
    for row in rows:
        by_run.setdefault(row["cameras"], {})[row["seed"]] = row
    means = {
        run: {"seeds": sorted(of_seed),
              **{k: _mean([r.get(k) for r in of_seed.values()]) for k in METRICS}}
        for run, of_seed in by_run.items()
    }  # fmt: skip
    gaps: dict[str, Any] = {}
    reference = by_run.get("dataset", {})
    for run, of_seed in by_run.items():
        if run == "dataset" or not reference:
            continue
        per_seed = {
            seed: scored - float(reference[seed]["psnr"])
            for seed, row in sorted(of_seed.items())
            if seed in reference and (scored := _scored_psnr(row)) is not None
            and reference[seed].get("psnr") is not None
        }  # fmt: skip
        gaps[run] = {"per_seed": per_seed, "mean": _mean(list(per_seed.values()))}
    return {"means": means, "psnr_gap": gaps}


def format_summary(summary: dict[str, Any]) -> str:
    """:func:`seed_summary`'s figures as lines of text: each run's mean metrics over its
    seeds, then each PSNR gap per seed and on average (dB, two decimals)."""

    def num(v: float | None, digits: int) -> str:
        return "-" if v is None else f"{v:.{digits}f}"

    lines = []
    for run, m in summary["means"].items():
        seeds = " ".join(str(s) for s in m["seeds"])
        lines.append(f"{run}: mean over seeds {seeds}: PSNR {num(m['psnr'], 2)} / "
                     f"SSIM {num(m['ssim'], 3)} / LPIPS {num(m['lpips'], 4)}")  # fmt: skip
    for run, gap in summary["psnr_gap"].items():
        per_seed = ", ".join(f"seed {s} {v:+.2f}" for s, v in gap["per_seed"].items())
        lines.append(f"{run} - dataset PSNR: {per_seed}; mean {num(gap['mean'], 2)} dB")
    return "\n".join(lines)


def results_name(
    scene: str, given: bool, seeds: Sequence[int], views: int | None = None, sets: bool = False
) -> str:
    """The result file's name: ``cameras-train-SCENE-MODE.json``, with ``-set`` when training
    settings were given (``--set``; the file records them), the training views (``-views-5``)
    unless the paper's and the seeds (``-seeds-1-2``) unless they are just 0 appended (the
    name before any could be chosen)."""
    mode = "given" if given else "estimated"
    suffix = "-set" if sets else ""
    suffix += "" if views is None else f"-views-{views}"
    suffix += "" if list(seeds) == [0] else "-seeds-" + "-".join(str(s) for s in seeds)
    return f"cameras-train-{scene}-{mode}{suffix}.json"


def _posed(old: Any, w2c: np.ndarray, intrinsics: tuple[float, float, float, float]) -> Any:
    """The engine camera ``old`` with the world-to-camera ``w2c`` (float64 NumPy, cast to
    ``old``'s pose dtype and device) and the pinhole ``intrinsics`` (fx, fy, cx, cy)."""
    import torch

    from sparsesplat.engine.camera import Camera

    pose = torch.from_numpy(w2c).to(old.world_to_camera)
    return Camera(pose, *intrinsics, old.width, old.height)


def _refined_alignment(trainer: Any, dataset: Any, by: str) -> tuple[Any, list[float]]:
    """The similarity taking the dataset's frame to ``trainer``'s (aligning its refined
    training cameras, or the scene seen through them, to the dataset's; ``by`` as in
    :func:`with_estimated_cameras`), and each refined camera's rotation error (degrees)."""
    from sparsesplat.engine.match.geometry import PinholeArrays
    from sparsesplat.engine.sfm.align import align, rotation_errors_deg

    cameras = trainer.training_cameras()
    model = [c.world_to_camera.double().cpu().numpy() for c in cameras]
    ref = [v.camera.world_to_camera.double().numpy() for v in dataset.train]
    if by == "scene":
        photos = [v.image for v in dataset.train]
        ref_cams = [PinholeArrays.of(v.camera) for v in dataset.train]
        sim = scene_alignment(photos, ref_cams, [PinholeArrays.of(c) for c in cameras])[0]
    else:
        sim = align(model, ref)
    return sim, rotation_errors_deg(model, ref, sim)


def refined_errors(trainer: Any, dataset: Any, by: str = "scene") -> dict[str, float]:
    """Median and largest rotation error (degrees) of ``trainer``'s refined training cameras
    against the dataset's after a similarity alignment (as ``cameras.measure`` scores the
    estimate itself)."""
    errors = _refined_alignment(trainer, dataset, by)[1]
    return {"median_deg": float(np.median(errors)), "max_deg": float(np.max(errors))}


def realigned_metrics(trainer: Any, dataset: Any, by: str = "scene") -> dict[str, float | None]:
    """``trainer``'s held-out metrics at the dataset's held-out cameras mapped into its frame
    by the similarity that aligns its (refined) training cameras to the dataset's."""
    import dataclasses

    sim = _refined_alignment(trainer, dataset, by)[0]
    scored = trainer.recorder.scene
    test = []
    for view in scored.test:
        old = view.camera
        w2c = sim.map_world_to_camera(old.world_to_camera.double().numpy())
        camera = _posed(old, w2c, (old.fx, old.fy, old.cx, old.cy))
        test.append(dataclasses.replace(view, camera=camera))
    trainer.recorder.scene = dataclasses.replace(scored, test=test)
    try:
        return trainer.evaluate()
    finally:
        trainer.recorder.scene = scored
