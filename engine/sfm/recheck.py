"""Whether a learned placement survives matching the photos at another size.

The learned matcher works on photos brought to one working size (small ones enlarged to 800
px, large ones shrunk to 1024). Matched at one size, the same photos can give a placement that
passes every other check and is still degrees off. mic's paper views 3-6 alone, for example:
at 800 px they were placed 3.5 / 5.2° off (photos 3 and 4), with an orientation spread of
0.88°, firmness moves of at most 0.71° and a reprojection error of 0.6 px. Matched at 1024 px,
the same photos moved by 1.4-3.5°. The placements the shared scenes get right move far less:
DTU's and LLFF's at most 0.5°, fox's at most 1.0° from a guessed focal length and 0.23° with
the focal length given (docs/experiments/2026-11-30-pose-refinement-rule.md). juicebox_table
had the same trouble, found earlier (docs/experiments/2026-11-30-firm-placement.md): 0.86°
off at 800 px, 3.55° off at 640, not placed at 720 or 960.

So after the other checks pass, the learned attempt matches and maps the photos once more at
another working size: 1024 px when they were matched smaller, else 800 px. Every photo it
placed must be placed again within :data:`MAX_MOVE_DEG` of where it was, after a similarity
alignment of the two solutions. Otherwise the attempt fails, naming the photo that moved
most, and the next attempt is tried.
"""

from __future__ import annotations

import dataclasses
import math
from pathlib import Path

from sparsesplat.engine.match.settings import MatchSettings, resize_factor
from sparsesplat.engine.sfm.align import align, rotation_errors_deg
from sparsesplat.engine.sfm.attempts import Attempt
from sparsesplat.engine.sfm.reconstruct import CameraPrior, Reconstruction, run_colmap

MAX_MOVE_DEG = 2.0
"""Largest accepted change of a photo's orientation between the two matching sizes: above
every correct placement measured (at most 1.0°), below the wrong ones (3.2° and more)."""
LARGER_SIDE = 1024
"""The second working size for photos first matched smaller than this..."""
SMALLER_SIDE = 800
"""... and for photos first matched at :data:`LARGER_SIDE` or more."""


def working_side(longer: int, min_side: int, max_side: int) -> int:
    """The longer side, in pixels, that the matcher works at for photos whose longer side is
    ``longer`` (``engine.match.settings.resize_factor``, as ``engine.match.images.prepare``
    resizes them)."""
    return round(longer * resize_factor(longer, min_side, max_side))


def second_size(attempt: Attempt, longer: int) -> tuple[Attempt, int, int]:
    """The attempt that matches photos with longer side ``longer`` at the other working
    size (without a recheck of its own), and the first and second working sizes."""
    defaults = MatchSettings()
    min_side = attempt.match_min_side if attempt.match_min_side is not None else defaults.min_side
    max_side = attempt.match_max_side if attempt.match_max_side is not None else defaults.max_side
    first = working_side(longer, min_side, max_side)
    if first < LARGER_SIDE:
        other = dataclasses.replace(
            attempt, match_min_side=LARGER_SIDE, match_max_side=max(max_side, LARGER_SIDE),
            recheck=False,
        )  # fmt: skip
        return other, first, working_side(longer, LARGER_SIDE, max(max_side, LARGER_SIDE))
    other = dataclasses.replace(
        attempt, match_min_side=min(min_side, SMALLER_SIDE), match_max_side=SMALLER_SIDE,
        recheck=False,
    )  # fmt: skip
    return other, first, working_side(longer, min(min_side, SMALLER_SIDE), SMALLER_SIDE)


def moves_deg(rec: Reconstruction, again: Reconstruction | None) -> dict[int, float]:
    """Photo index -> how far its orientation moved from ``rec`` to ``again`` (degrees, after
    aligning ``again`` to ``rec`` on the photos both placed); inf for a photo ``again`` did
    not place, and for every photo when fewer than two were placed in both."""
    placed = sorted(rec.world_to_camera)
    both = [i for i in placed if again is not None and i in again.world_to_camera]
    moved = dict.fromkeys(placed, math.inf)
    if again is None or len(both) < 2:
        return moved
    est = [again.world_to_camera[i] for i in both]
    ref = [rec.world_to_camera[i] for i in both]
    for i, error in zip(both, rotation_errors_deg(est, ref, align(est, ref)), strict=True):
        moved[i] = float(error) if math.isfinite(error) else math.inf
    return moved


def move_problem(names: list[str], moved: dict[int, float], first: int, second: int) -> str | None:
    """Why the placement does not survive the second matching size (naming the photo that
    moved most); None when every photo stayed within :data:`MAX_MOVE_DEG`."""
    if not moved or max(moved.values()) <= MAX_MOVE_DEG:
        return None
    i = max(moved, key=lambda k: (moved[k], -k))
    what = f"moved {moved[i]:.1f}°" if math.isfinite(moved[i]) else "could not be placed again"
    return (
        f"photo {i + 1} ({names[i]}) {what} when the photos were matched at {second} px "
        f"instead of {first} px (at most {MAX_MOVE_DEG:g}° accepted): its matches do not pin "
        "it down, so the estimate may be a wrong frame; take the photos closer together with "
        "more overlap, or fill more of the frame with the object"
    )


def recheck(
    image_dir: Path,
    names: list[str],
    shown: list[str],
    longer: int,
    prior: CameraPrior,
    attempt: Attempt,
    rec: Reconstruction,
    work_dir: Path,
    threads: int,
    seed: int,
) -> str | None:
    """Match and map the photos ``names`` (files in ``image_dir``, longer side ``longer``
    pixels) again at the other working size (:func:`second_size`) in ``work_dir`` and compare
    with ``rec``: the problem (naming photos by ``shown``), or None when every photo stays."""
    other, first, second = second_size(attempt, longer)
    again, _ = run_colmap(image_dir, names, prior, other, work_dir, threads, seed)
    return move_problem(shown, moves_deg(rec, again), first, second)
