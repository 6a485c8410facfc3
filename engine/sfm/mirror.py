"""Tell a mirrored photo from one that is merely out of reach, before it is left out.

A photo flipped left to right (a selfie camera, an editor's "flip") shows the scene with its
handedness reversed: no camera could have taken it, so it matches the others poorly and is not
placed. Leaving it out silently would lose a view the user meant to give; its mirror image,
matched against the placed photos, tells the two cases apart. When the mirror image shares a
fundamental matrix's worth of matches with a placed photo and the photo as it is does not, the
set is refused naming the photo, so the user can put the original back.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from sparsesplat.engine.match import MatchSettings, match_images
from sparsesplat.engine.match.errors import MissingMatchDependency
from sparsesplat.engine.sfm.colmap import require_pycolmap
from sparsesplat.engine.sfm.learned import load_photo

MATCHER = "xfeat-lighterglue"
"""The matcher that looks for the mirror image's matches (the learned attempt's)."""
MIN_MATCHES = 30
"""Fewest consistent matches between a mirror image and a placed photo that count as the
photo being mirrored, whatever the attempt's own threshold: the learned attempt's
verification threshold. A few are found by chance on a nearly symmetric object (mic's 8
paper views: 12 between the flipped photo 7 and photo 3, with the retry's threshold of 12
the photo was called mirrored); a mirrored photo of the textured test scene gives 1294."""
RANSAC_MAX_ERROR_PX = 4.0
"""Epipolar distance within which a match agrees with the fundamental matrix (COLMAP's
two-view verification default)."""


def consistent_matches(photo: np.ndarray, mask: np.ndarray | None, other: np.ndarray,
                       other_mask: np.ndarray | None, seed: int) -> int:  # fmt: skip
    """Matches between two photos that agree with one fundamental matrix (LO-RANSAC)."""
    pycolmap = require_pycolmap()
    found = match_images([photo, other], MatchSettings(method=MATCHER), [mask, other_mask])
    rows = found.matches.get((0, 1), np.zeros((0, 2), np.int64))
    if len(rows) < 8:
        return 0
    options = pycolmap.RANSACOptions()
    options.max_error = RANSAC_MAX_ERROR_PX
    options.random_seed = seed
    a = np.ascontiguousarray(found.keypoints[0][rows[:, 0]], dtype=np.float64)
    b = np.ascontiguousarray(found.keypoints[1][rows[:, 1]], dtype=np.float64)
    result = pycolmap.estimate_fundamental_matrix(a, b, options)
    return int(result["num_inliers"]) if result else 0


def mirrored(
    image_dir: Path, names: list[str], candidates: list[int], placed: list[int],
    min_inliers: int, seed: int = 0,
) -> dict[int, tuple[int, int]]:  # fmt: skip
    """Of the photos ``candidates`` (about to be left out), those whose mirror image matches a
    placed photo (at least ``min_inliers`` and :data:`MIN_MATCHES` consistent matches, and
    more than twice the photo's own): index -> (that photo, the mirror image's consistent
    matches). Empty when the learned matcher is not installed (the photo is then left out as
    unplaceable)."""
    need = max(min_inliers, MIN_MATCHES)
    found: dict[int, tuple[int, int]] = {}
    try:
        photos = {i: load_photo(image_dir / names[i]) for i in [*candidates, *placed]}
        for i in candidates:
            image, mask = photos[i]
            flipped = np.ascontiguousarray(image[:, ::-1])
            flipped_mask = None if mask is None else np.ascontiguousarray(mask[:, ::-1])
            best = (-1, 0)
            for j in placed:
                count = consistent_matches(flipped, flipped_mask, *photos[j], seed)
                if count > best[1]:
                    best = (j, count)
            if best[1] >= need:
                as_is = consistent_matches(image, mask, *photos[best[0]], seed)
                if best[1] > 2 * as_is:
                    found[i] = best
    except MissingMatchDependency:
        return {}
    return found
