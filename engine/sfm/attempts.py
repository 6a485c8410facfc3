"""The settings tried, in order: COLMAP with a relaxed initialisation, then a retry that finds
more features and accepts fewer inliers (small, weakly textured or far-apart photos)."""

from __future__ import annotations

from dataclasses import dataclass


@dataclass(frozen=True)
class Attempt:
    """One configuration of feature extraction, matching and incremental mapping."""

    name: str
    """Short name reported with the result."""
    peak_threshold: float
    """SIFT detection threshold (COLMAP's default 0.0067; lower finds more, weaker features)."""
    domain_size_pooling: bool
    """SIFT descriptors pooled over several scales (more robust matches on few features)."""
    affine_shape: bool
    """Affine-adapted SIFT (matches across wider viewpoint changes, slower)."""
    guided_matching: bool
    """A second matching pass guided by the first pass's epipolar geometry."""
    min_inliers: int
    """Fewest geometrically verified matches for a pair, the initial pair and a new view."""
    init_min_tri_angle_deg: float
    """Smallest median triangulation angle of the initial pair (COLMAP's default is 16°,
    which a forward-facing capture of three photos never reaches)."""
    matcher: str | None = None
    """A learned matcher of ``engine.match`` (its keypoints and matches replace SIFT's; the
    SIFT fields above then only register the photos), or None for COLMAP's SIFT matching."""
    match_min_side: int | None = None
    """With ``matcher``: the size photos are enlarged to before matching
    (``MatchSettings.min_side``); None keeps the matcher's default. A lever for measuring how
    firm an estimate is (``benchmarks/cameras.py --match-side``), not a setting to tune."""
    match_max_side: int | None = None
    """With ``matcher``: the size larger photos are shrunk to before matching
    (``MatchSettings.max_side``); None keeps the matcher's default. Set by the matching-size
    check (:mod:`.recheck`), not a setting to tune."""
    recheck: bool = False
    """With ``matcher``: once placed, the photos are matched again at another working size and
    mapped again; a photo that moves more than ``recheck.MAX_MOVE_DEG`` fails the attempt
    (:mod:`.recheck`)."""
    known_focal_only: bool = False
    """Whether the attempt runs only when the focal length is known (given, or from EXIF).
    On for the weakest attempt: from a guess its placements of object captures were wrong
    frames that no check told from good ones. mic's 8 paper views: 4 placed with the focal
    length 22 % short, rotations 2-4° off, trained 7 dB below the dataset's cameras
    (docs/experiments/2026-11-30-mic-enlarged.md); mic's photos 3-6 alone: all 4 placed 2.1-10.5°
    off (docs/experiments/2026-11-30-pose-refinement-rule.md). With the focal length given it
    places both sets within 1.6°."""
    enlarge_to: int | None = None
    """For COLMAP's SIFT, when the focal length is known (given or EXIF): photos whose longer
    side is under this many pixels are enlarged by the smallest whole factor that reaches it
    (:mod:`.enlarge`) before features are found, and the result is brought back to the
    photos' own pixels; None: the photos as they are."""


ATTEMPTS: tuple[Attempt, ...] = (
    # Measured on the 3 training views of LLFF flower: 478 points, 0.34 px, all registered.
    Attempt("relaxed", 0.02 / 3, False, False, False, 30, 1.0),
    # XFeat + LighterGlue keypoints and matches, verified and mapped by COLMAP: places photos
    # 20-45 degrees apart around an object, which SIFT cannot match. Runs when the match
    # extra is installed, from a known or a guessed focal length (the firmness check refuses
    # the wrong frames a guess once led it to).
    # Its placement is checked by matching once more at another size (mic's photos 3-6
    # alone: placed 3.5 / 5.2 degrees off at 800 px, moved 3.2 degrees at 1024 px, where
    # every other check passed; docs/experiments/2026-11-30-pose-refinement-rule.md).
    Attempt(
        "learned",
        0.02 / 3,
        False,
        False,
        False,
        30,
        1.0,
        matcher="xfeat-lighterglue",
        recheck=True,
    ),
    # Small photos enlarged to 800 px (with a known focal length): SIFT's finest scale then
    # finds the detail that makes mic's 8 paper views (400 px) placeable, 4 of them within
    # 0.4-1.5 degrees (the other 4, 130-170 degrees from those or matching none, left out by
    # name), where at 400 px this attempt placed the same 4 up to 7 degrees off
    # (docs/experiments/2026-11-30-mic-enlarged.md).
    Attempt(
        "more features",
        0.002,
        True,
        False,
        True,
        12,
        0.5,
        known_focal_only=True,
        enlarge_to=800,
    ),
)
"""Tried in order until a result places every photo and passes every check (:mod:`.check`).
A third, affine-adapted SIFT with 10 inliers, registered DTU scan24's three views with
0.55-0.67 px reprojection error but 3-11° rotation error against the dataset: a wrong frame
that passes every check, so it is not tried (docs/experiments/2026-11-25-camera-estimation.md)."""
