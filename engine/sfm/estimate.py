"""Estimate the cameras of a few photos: the entry point of ``engine.sfm``."""

from __future__ import annotations

import logging
import tempfile
import time
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from sparsesplat.api.camera_estimation import PhotoPlacement
from sparsesplat.api.cameras import (
    MIN_PHOTOS,
    AxisConvention,
    CameraFrame,
    CamerasFile,
    Intrinsics,
    PoseDirection,
    rigid_inverse,
)
from sparsesplat.engine.match.errors import MissingMatchDependency
from sparsesplat.engine.sfm.attempts import ATTEMPTS, Attempt
from sparsesplat.engine.sfm.check import (
    best_partner,
    input_problem,
    left_out,
    median_triangulation_angle_deg,
    photo,
    result_problem,
    rotation_std_by_photo,
)
from sparsesplat.engine.sfm.enlarge import enlarge_factor, write_enlarged
from sparsesplat.engine.sfm.errors import CameraEstimationError
from sparsesplat.engine.sfm.exif import exif_focal_px
from sparsesplat.engine.sfm.firmness import firmness
from sparsesplat.engine.sfm.frame import normalise
from sparsesplat.engine.sfm.mirror import mirrored
from sparsesplat.engine.sfm.recheck import recheck
from sparsesplat.engine.sfm.reconstruct import (
    CameraPrior,
    MatchStats,
    Reconstruction,
    run_colmap,
)
from sparsesplat.engine.sfm.uncertainty import residuals

log = logging.getLogger(__name__)

FOCAL_GUESSED = (
    "the focal length was guessed (no intrinsics given, no EXIF): giving it (the intrinsics, "
    "or photos with their EXIF) leaves bundle adjustment fewer ways to go wrong"
)
"""Added to a refusal when the focal length was a guess."""
DEFAULT_FOCAL_FACTOR = 1.2
"""Focal length guess without EXIF or user intrinsics: this times the longer image side
(COLMAP's own default, a ~45° field of view); bundle adjustment refines it."""


@dataclass
class CameraEstimate:
    """Estimated cameras in the one camera schema, with the sparse points."""

    cameras: CamerasFile
    """OpenCV camera-to-world frames of the placed photos (their own file names, all
    ``train``), near/far and the init box, in the normalised frame (:mod:`.frame`)."""
    points: np.ndarray
    """(N, 3) float32 triangulated points, same frame."""
    colours: np.ndarray
    """(N, 3) float32 RGB in [0, 1] of the points."""
    seconds: float
    """Wall time of the estimation."""
    attempt: str
    """Name of the settings that succeeded (:data:`.attempts.ATTEMPTS`)."""
    reprojection_error_px: float
    """Mean reprojection error of the points (pixels)."""
    triangulation_angle_deg: float
    """Median triangulation angle of the points (degrees)."""
    focal_source: str
    """Where the starting focal length came from: 'given', 'exif' or 'guess'."""
    photos: list[PhotoPlacement]
    """Each photo in the order given: placed or left out (with the reason), its matches,
    points, error and how firmly its orientation is fixed."""

    @property
    def left_out(self) -> list[PhotoPlacement]:
        """The photos without a camera (each names why)."""
        return [p for p in self.photos if not p.placed]

    def summary(self) -> dict[str, Any]:
        """The figures reported with a job (views, points, error, angle, seconds, photos)."""
        return {
            "views": len(self.cameras.frames),
            "points": len(self.points),
            "reprojection_error_px": round(self.reprojection_error_px, 3),
            "triangulation_angle_deg": round(self.triangulation_angle_deg, 2),
            "seconds": round(self.seconds, 2),
            "attempt": self.attempt,
            "focal": self.focal_source,
            "photos": [p.model_dump(mode="json") for p in self.photos],
        }


def estimate_cameras(
    paths: list[Path],
    intrinsics: Intrinsics | None = None,
    *,
    threads: int = 1,
    seed: int = 0,
    labels: list[str] | None = None,
    attempts: Sequence[Attempt] = ATTEMPTS,
) -> CameraEstimate:
    """Estimate one shared pinhole camera and a pose per photo in ``paths`` (all the same
    size), or raise :class:`CameraEstimationError` naming the photos at fault and what to do.

    ``intrinsics`` are held fixed when given; else an EXIF focal length (35 mm equivalent) or
    1.2x the longer side starts bundle adjustment. Messages name the photos by ``labels``
    (e.g. the names they were uploaded under; default: their file names). The settings of
    ``attempts`` (default :data:`ATTEMPTS`) are tried in order until a result passes every
    check of :mod:`.check`; raises ValueError when there are none."""
    started = time.perf_counter()
    names = [p.name for p in paths]
    shown = labels if labels is not None else names
    if len(shown) != len(paths):
        raise ValueError(f"{len(shown)} labels for {len(paths)} photos")
    if not attempts:
        raise ValueError("no camera estimation attempts to try")
    if len(paths) < MIN_PHOTOS:
        raise CameraEstimationError(
            f"need at least {MIN_PHOTOS} photos of the same scene from different places to "
            f"estimate cameras, got {len(paths)}"
        )
    if len(set(names)) != len(names):
        raise CameraEstimationError("two photos have the same file name: rename one")
    width, height = _common_size(paths, shown)
    prior, source = _prior(paths, width, height, intrinsics)
    problem: str | None = None
    rec: Reconstruction | None = None
    furthest: tuple[int, str] | None = None  # the failed attempt that placed most photos, why
    with tempfile.TemporaryDirectory(prefix="sparsesplat-sfm-") as tmp:
        image_dir = paths[0].parent
        if any(p.parent != image_dir for p in paths):
            raise CameraEstimationError("the photos must be in one folder")
        # Every attempt runs whatever the focal length's source. From a guess the learned one
        # once returned a wrong frame (juicebox_table: focal 40 % off, rotations 4.5-5.8
        # degrees) and ran only with a known focal; the firmness check now refuses that frame
        # (its second photo is lost in 3 of 4 tries) and places fox and DTU within 0.6
        # degrees from a guess (docs/experiments/2026-11-30-firm-placement.md).
        for k, attempt in enumerate(attempts):
            if attempt.known_focal_only and source == "guess":
                continue  # its frames from a guess were wrong, and passed every check
            work = Path(tmp) / str(k)
            # Enlarged only with a known focal length: from a guess, mic's enlarged retry
            # put the focal 22 % off with 4 of 8 photos placed 2-4 degrees off, a result that
            # trained 7 dB below the dataset's cameras and that no check here tells from a
            # good one (docs/experiments/2026-11-30-mic-enlarged.md).
            target = attempt.enlarge_to if source != "guess" else None
            factor = enlarge_factor(width, height, target)
            photo_dir = image_dir
            if factor > 1:  # COLMAP sees the photos enlarged; its result is scaled back below
                photo_dir = write_enlarged(image_dir, names, work / "enlarged", factor)
            used = prior.scaled(factor)
            try:
                rec, stats = run_colmap(photo_dir, names, used, attempt, work, threads, seed)
            except MissingMatchDependency as exc:  # no match extra: SIFT's attempts follow
                log.warning("learned matching unavailable, trying SIFT: %s", exc)
                continue
            if factor > 1:  # every check and the result in the photos' own pixels
                stats = stats.scaled(1 / factor)
                rec = None if rec is None else rec.scaled(1 / factor)
            problem = input_problem(shown, stats)
            if problem is not None:  # a blank photo or copies of one view: no setting helps
                break
            problem = result_problem(shown, stats, rec, attempt.min_inliers)
            if problem is None and rec is not None:
                problem = firmness(
                    work / "database.db", photo_dir, names, used, attempt, rec, threads, seed
                ).problem(shown)
            if problem is None and rec is not None and attempt.recheck:
                problem = recheck(photo_dir, names, shown, max(width, height) * factor, used,
                                  attempt, rec, work / "recheck", threads, seed)  # fmt: skip
            log.info("camera estimation attempt", extra={"attempt": attempt.name,
                                                         "problem": problem})  # fmt: skip
            if problem is None:
                break
            placed = 0 if rec is None else len(rec.world_to_camera)
            if furthest is None or placed > furthest[0]:
                furthest = (placed, problem)
        else:
            # No attempt passed: say why the one that got furthest failed (a later retry
            # that placed fewer photos would blame matches the earlier one had).
            if furthest is not None:
                problem = furthest[1]
    if problem is None and rec is None:  # every attempt unavailable (no match extra)
        problem = "no matching attempt could run"
    if problem is not None or rec is None:
        hint = f"; {FOCAL_GUESSED}" if source == "guess" else ""
        raise CameraEstimationError(f"cannot estimate the cameras: {problem}{hint}")
    reasons = left_out(shown, stats, rec, attempts[k].min_inliers) or {}
    if reasons:
        _refuse_mirrored(image_dir, names, shown, reasons, rec, stats, attempts[k].min_inliers,
                         seed)  # fmt: skip
    for _, reason in sorted(reasons.items()):
        log.warning("photo left out of the camera estimate: %s", reason)
    frame = normalise(rec)
    fx, fy, cx, cy = rec.intrinsics
    photos = photo_report(shown, stats, rec, reasons)
    frames = [
        CameraFrame(
            image=name,
            matrix=rigid_inverse(frame.world_to_camera[i].tolist()),
            fx=fx,
            fy=fy,
            cx=cx,
            cy=cy,
            width=width,
            height=height,
            rotation_std_deg=photos[i].rotation_std_deg,
        )
        for i, name in enumerate(names)
        if i in frame.world_to_camera
    ]
    cameras = CamerasFile(
        convention=AxisConvention.opencv,
        pose=PoseDirection.camera_to_world,
        frames=frames,
        near=frame.near,
        far=frame.far,
        init_box=frame.init_box,
    )
    return CameraEstimate(
        cameras=cameras,
        points=frame.points.astype(np.float32),
        colours=rec.colours,
        seconds=time.perf_counter() - started,
        attempt=attempts[k].name,
        reprojection_error_px=rec.reprojection_error_px,
        triangulation_angle_deg=median_triangulation_angle_deg(rec),
        focal_source=source,
        photos=photos,
    )


def _refuse_mirrored(
    image_dir: Path, names: list[str], shown: list[str], reasons: dict[int, str],
    rec: Reconstruction, stats: MatchStats, min_inliers: int, seed: int,
) -> None:  # fmt: skip
    """Raise when a photo about to be left out is mirrored (:mod:`.mirror`): the user meant
    to give it, and the original would be placed.

    Only a photo that as it is shares fewer than ``min_inliers`` verified matches with every
    other photo of the set is a suspect: a mirrored photo's handedness is the reverse of all
    the others'. One that matches another photo as it is (two left-out photos that are
    neighbours of each other) is out of the placed photos' reach, not mirrored; a nearly
    symmetric object's mirror image matches a view from the far side. (mic's 8 paper views
    at 800 px: photos 2 and 8, 130-170 degrees from the four placed ones, share 88 matches
    with each other, and their mirror images 131 and 167 with photo 3.)"""
    suspects = [
        i for i in sorted(reasons)
        if stats.inliers(i, best_partner(stats, len(names), i)) < min_inliers
    ]  # fmt: skip
    if not suspects:
        return
    flipped = mirrored(image_dir, names, suspects, sorted(rec.world_to_camera), min_inliers, seed)
    if flipped:
        i, (j, count) = min(flipped.items())
        raise CameraEstimationError(
            f"cannot estimate the cameras: {photo(shown, i)} looks mirrored (flipped left to "
            f"right): flipped back it shares {count} consistent matches with "
            f"{photo(shown, j)}, as it is it cannot be placed; give the camera's original photo"
        )


def photo_report(
    names: list[str], stats: MatchStats, rec: Reconstruction, reasons: dict[int, str]
) -> list[PhotoPlacement]:
    """Per photo (in the order of ``names``): placed or left out with ``reasons[i]``, its
    verified matches, and for a placed one its points, mean reprojection error and
    orientation spread."""
    placed, problem = rec.bundle_problem()
    error = np.linalg.norm(residuals(problem), axis=1)
    spread = rotation_std_by_photo(rec)
    report = []
    for i, name in enumerate(names):
        matches = sum(stats.inliers(i, j) for j in range(len(names)) if j != i)
        if i not in rec.world_to_camera:
            report.append(PhotoPlacement(name=name, placed=False, matches=matches,
                                         reason=reasons.get(i)))  # fmt: skip
            continue
        mine = problem.camera_index == placed.index(i)
        report.append(
            PhotoPlacement(
                name=name,
                placed=True,
                matches=matches,
                points=int(mine.sum()),
                error_px=_finite(float(error[mine].mean())) if mine.any() else None,
                rotation_std_deg=_finite(spread[i]),
            )
        )
    return report


def _finite(value: float) -> float | None:
    """``value`` to 3 decimals, or None when it is not finite (a degenerate solution), so that
    the report stays valid JSON."""
    return round(value, 3) if np.isfinite(value) else None


def _common_size(paths: list[Path], shown: list[str]) -> tuple[int, int]:
    from PIL import Image, UnidentifiedImageError

    sizes = []
    for i, path in enumerate(paths):
        try:
            with Image.open(path) as image:
                sizes.append(image.size)
        except (OSError, UnidentifiedImageError) as exc:
            raise CameraEstimationError(
                f"photo {i + 1} ({shown[i]}) is not a readable image ({exc})"
            ) from exc
    for i, size in enumerate(sizes):
        if size != sizes[0]:
            raise CameraEstimationError(
                f"photo {i + 1} ({shown[i]}) is {size[0]}x{size[1]} but photo 1 "
                f"({shown[0]}) is {sizes[0][0]}x{sizes[0][1]}: the photos must come from "
                "one camera at one size"
            )
    return sizes[0]


def _prior(
    paths: list[Path], width: int, height: int, intrinsics: Intrinsics | None
) -> tuple[CameraPrior, str]:
    if intrinsics is not None:
        i = intrinsics
        if i.size is not None and i.size != (width, height):
            raise CameraEstimationError(
                f"the intrinsics are for {i.size[0]}x{i.size[1]} images but the photos are "
                f"{width}x{height}"
            )
        return CameraPrior(i.fx, i.fy, i.cx, i.cy, fixed=True), "given"
    exif = [f for f in (exif_focal_px(p, width, height) for p in paths) if f is not None]
    focal, source = (
        (float(np.median(exif)), "exif")
        if exif
        else (DEFAULT_FOCAL_FACTOR * max(width, height), "guess")
    )
    return CameraPrior(focal, focal, width / 2, height / 2, fixed=False), source
