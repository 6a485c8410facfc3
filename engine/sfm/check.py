"""Judge a reconstruction, and say in a photographer's words why photos cannot be placed.

A result is accepted when enough points were triangulated, they reproject within a few pixels
and the photos were taken from far enough apart for depth (the median triangulation angle).
Every photo must be placed, with one exception: photos that share no verified match with any
placed photo (outside the matcher's reach) are left out by name when at least three photos and
half of the set are placed, and every placed photo's orientation is pinned down by its matches
(:mod:`.uncertainty`). A photo that does share matches with the placed ones but could not be
placed with them sinks the set: its matches contradict the solution. Otherwise the match
statistics tell why: a blank photo, copies of one view, or photos that share too few features.
"""

from __future__ import annotations

import math

import numpy as np

from sparsesplat.engine.sfm.reconstruct import MatchStats, Reconstruction
from sparsesplat.engine.sfm.uncertainty import relative_rotation_std_deg

MIN_FEATURES = 40
"""A photo with fewer SIFT features has nothing to match (blank, blurred, too dark)."""
SAME_VIEW_PX = 1.0
"""Matches that move less than this (median, pixels) come from copies of one view."""
MIN_POINTS = 20
"""Fewest triangulated points for a usable result."""
MAX_REPROJECTION_PX = 2.0
"""Largest mean reprojection error accepted (pixels)."""
MATCHER_REACH = (
    "each photo needs a neighbour taken within roughly 45 degrees around the object (beyond "
    "that the learned matcher finds few matches, and none between views 80-98 degrees apart "
    "in our tests): take the photos closer together, with more overlap"
)
"""What a photo without a placed neighbour is told."""
MAX_ROTATION_STD_DEG = 1.5
"""Largest accepted spread (one standard deviation) of a placed photo's orientation relative
to another's, in a set with photos left out. The correct 3-view solutions of the shared scenes
measure at most 0.79° (juicebox_table; DTU 0.22-0.44°, LLFF 0.06-0.16°, fox 0.26°), four
neighbouring views of mic with a far one left out 0.8-1.4°; the partial, wrong frames of mic's
8 views 1.7° (SIFT's retry, 2.1-7.0° off) and 2.7° (learned, 4.6-21° off), beer_can's two
placed views 2.4° (docs/experiments/2026-11-29-camera-uncertainty.md)."""
MIN_PHOTOS_PLACED = 3
"""Fewest photos placed for a set with photos left out (a scene needs three to train)."""
MIN_PLACED_FRACTION = 0.5
"""A set with photos left out is accepted only when at least this fraction of it is placed."""
MIN_TRIANGULATION_DEG = 0.2
"""Smallest median triangulation angle accepted: below it depth is guesswork (the three
forward-facing LLFF views measure about 1-3°)."""


def photo(names: list[str], i: int) -> str:
    """``photo 2 (b.jpg)``: 1-based, as the user numbered them, with the file name."""
    return f"photo {i + 1} ({names[i]})"


def photos(names: list[str], i: int, j: int) -> str:
    """``photos 1 (a.jpg) and 2 (b.jpg)``."""
    return f"photos {i + 1} ({names[i]}) and {j + 1} ({names[j]})"


def best_partner(stats: MatchStats, n: int, i: int) -> int:
    """The photo of ``n`` (other than ``i``) that shares most verified matches with photo
    ``i`` (the first such on a tie)."""
    return max((j for j in range(n) if j != i), key=lambda j: stats.inliers(i, j))


def input_problem(names: list[str], stats: MatchStats) -> str | None:
    """A problem of the photos themselves that no setting can fix: a featureless photo, or
    copies of one view. None when there is none."""
    for i, count in enumerate(stats.keypoints):
        if count < MIN_FEATURES:
            return (
                f"{photo(names, i)} has almost nothing to match ({count} features): it looks "
                "blank, blurred or too dark; retake it or leave it out"
            )
    for (i, j), pair in sorted(stats.pairs.items()):
        if pair.inliers >= MIN_POINTS and pair.displacement_px < SAME_VIEW_PX:
            return (
                f"{photos(names, i, j)} show the same view (their features did not move "
                f"between them): a copy adds no depth; step sideways between shots"
            )
    return None


def median_triangulation_angle_deg(rec: Reconstruction) -> float:
    """Median over points of the widest angle between two of its observing cameras' rays."""
    centres = {i: -w2c[:3, :3].T @ w2c[:3, 3] for i, w2c in rec.world_to_camera.items()}
    angles = []
    for point, views in zip(rec.points, rec.point_views, strict=True):
        rays = [point - centres[v] for v in views if v in centres]
        rays = [r / np.linalg.norm(r) for r in rays if np.linalg.norm(r) > 0]
        widest = 0.0
        for a in range(len(rays)):
            for b in range(a + 1, len(rays)):
                widest = max(widest, math.acos(float(np.clip(rays[a] @ rays[b], -1.0, 1.0))))
        angles.append(widest)
    return math.degrees(float(np.median(angles))) if angles else 0.0


def left_out(
    names: list[str], stats: MatchStats, rec: Reconstruction, min_inliers: int
) -> dict[int, str] | None:
    """The photos ``rec`` did not place, each with the reason it may be left out, when the
    rest may stand (:data:`MIN_PHOTOS_PLACED`, :data:`MIN_PLACED_FRACTION`, and no left-out
    photo shares ``min_inliers`` verified matches with a placed one); None when they sink the
    set. Empty when every photo is placed."""
    placed = set(rec.world_to_camera)
    missing = [i for i in range(len(names)) if i not in placed]
    if not missing:
        return {}
    if len(placed) < MIN_PHOTOS_PLACED or len(placed) < MIN_PLACED_FRACTION * len(names):
        return None
    reasons = {}
    for i in missing:
        linked = [j for j in placed if stats.inliers(i, j) >= min_inliers]
        if linked:
            return None
        partner = best_partner(stats, len(names), i)
        reasons[i] = (
            f"{photo(names, i)} was left out: it shares no verified matches with the placed "
            f"photos (its best match: {stats.inliers(i, partner)} with "
            f"{photo(names, partner)}); {MATCHER_REACH}"
        )
    return reasons


def result_problem(
    names: list[str], stats: MatchStats, rec: Reconstruction | None, min_inliers: int
) -> str | None:
    """Why ``rec`` is not acceptable (None when it passes every check; photos it left out are
    then those :func:`left_out` names)."""
    n = len(names)
    if rec is None or len(rec.world_to_camera) < 2:
        return _no_start(names, stats, min_inliers)
    missing = [i for i in range(n) if i not in rec.world_to_camera]
    if missing and left_out(names, stats, rec, min_inliers) is None:
        # A photo linked to the placed ones by verified matches yet not placed with them
        # contradicts the solution: such partial sets were measured to be wrong frames (mic's
        # 8 paper views: 5 placed 5-21 degrees off the dataset's rotations;
        # docs/experiments/2026-11-28-object-cameras.md), so the whole set is refused.
        others = (
            f" ({len(missing) - 1} other photo(s) could not be placed either: "
            f"{', '.join(photo(names, k) for k in missing[1:])})"
            if len(missing) > 1
            else ""
        )
        return f"{unplaced_reason(names, stats, missing[0])}{others}"
    if len(rec.points) < MIN_POINTS:
        return (
            f"only {len(rec.points)} points could be triangulated (at least {MIN_POINTS} "
            "needed): take the photos closer together, of a more textured scene"
        )
    if rec.reprojection_error_px > MAX_REPROJECTION_PX:
        return (
            f"the estimated cameras do not fit the photos (mean reprojection error "
            f"{rec.reprojection_error_px:.1f} px, at most {MAX_REPROJECTION_PX:g}): did the "
            "scene move, or do the photos come from different cameras or zoom settings?"
        )
    angle = median_triangulation_angle_deg(rec)
    if angle < MIN_TRIANGULATION_DEG:
        return (
            f"the photos were taken from almost the same place (median triangulation angle "
            f"{angle:.2f}°, at least {MIN_TRIANGULATION_DEG:g}° needed): step sideways "
            "between shots"
        )
    # A set with photos left out must be firmly placed; a complete set is not held to this
    # (mic's four neighbouring views at 400 px, placed within 2 degrees, measure 1.1-1.4°, and
    # fewer pixels widen it further), since its photos were all placed by their own matches.
    return _loose_photo(names, rec) if missing else None


def rotation_std_by_photo(rec: Reconstruction) -> dict[int, float]:
    """Placed photo index -> the largest spread (degrees, one standard deviation) of its
    orientation relative to another placed photo's (:mod:`.uncertainty`)."""
    placed, problem = rec.bundle_problem()
    spread = relative_rotation_std_deg(problem)
    return {i: float(spread[row].max()) for row, i in enumerate(placed)}


def _loose_photo(names: list[str], rec: Reconstruction) -> str | None:
    spread = rotation_std_by_photo(rec)
    i = max(spread, key=lambda k: spread[k])
    if not spread[i] <= MAX_ROTATION_STD_DEG:  # also catches nan and inf
        by = f"{spread[i]:.1f}°" if math.isfinite(spread[i]) else "any angle"
        return (
            f"{photo(names, i)} is placed but its matches do not pin it down: its direction "
            f"could be off by {by} (one standard deviation; at most "
            f"{MAX_ROTATION_STD_DEG:g}° accepted), so the estimate may be a wrong frame. The "
            "matched detail covers too little of the photos: fill more of the frame with the "
            "object, use larger photos, or take them closer together"
        )
    return None


def unplaced_reason(names: list[str], stats: MatchStats, i: int) -> str:
    """Why photo ``i`` was left out: its best partner and their match count."""
    partner = best_partner(stats, len(names), i)
    return (
        f"{photo(names, i)} could not be placed: it shares too few features with the others "
        f"(at most {stats.inliers(i, partner)} verified matches, with {photo(names, partner)}); "
        f"{MATCHER_REACH}"
    )


def _no_start(names: list[str], stats: MatchStats, min_inliers: int) -> str:
    n = len(names)
    pairs = [(i, j) for i in range(n) for j in range(i + 1, n)]
    i, j = max(pairs, key=lambda p: stats.inliers(*p))
    best = stats.inliers(i, j)
    if best < min_inliers:
        # No photo has a partner within reach, so each one is named with its best partner:
        # which photos come nearest tells the user where to add one (mic's three paper views,
        # 64-132 degrees apart, have 0 verified matches in every pair).
        nearest = "; ".join(
            f"{photo(names, k)}: {stats.inliers(k, m)} with {photo(names, m)}"
            for k, m in ((k, best_partner(stats, n, k)) for k in range(n))
        )
        return (
            f"no two photos share enough features to start from (at least {min_inliers} "
            f"verified matches needed; each photo's best: {nearest}): the photos must show "
            f"one scene, and {MATCHER_REACH}"
        )
    return (
        f"{photos(names, i, j)} match ({best} matches) but show too little parallax to "
        "place them in 3D: step sideways between shots rather than turning on the spot"
    )
