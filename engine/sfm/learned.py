"""Learned keypoints and matches (``engine.match``) as COLMAP's features and matches.

COLMAP's own SIFT cannot match photos taken 20-90 degrees apart around an object; XFeat +
LighterGlue can (docs/experiments/2026-11-28-matchers.md). The photos are first registered in
the database by COLMAP's extractor (which writes the camera, rig, frame and image rows its
mapper needs), then each photo's SIFT keypoints are replaced by the learned ones, the learned
matches written for every pair, and COLMAP's two-view geometric verification (RANSAC) keeps
the consistent ones. Mapping and the checks of :mod:`.check` are the same as for SIFT.

A photo's alpha channel (an object composited on a plain backdrop, e.g. NeRF-synthetic) is
its mask: keypoints on the transparent backdrop are dropped, and so are keypoints on flat
patches (``MatchSettings.min_texture``): a white or black backdrop carries no evidence of
where a camera stood, however confidently two patches of it were matched.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from sparsesplat.engine.match import MatchSet, MatchSettings, match_images


def load_photo(path: Path) -> tuple[np.ndarray, np.ndarray | None]:
    """(H, W, 3) uint8 RGB of a photo, and its (H, W) bool mask from an alpha channel (None
    when it has none, or when the alpha is opaque everywhere)."""
    from PIL import Image

    with Image.open(path) as image:
        if image.mode in ("RGBA", "LA") or (image.mode == "P" and "transparency" in image.info):
            rgba = np.asarray(image.convert("RGBA"))
            alpha = rgba[..., 3]
            mask = alpha > 127 if (alpha < 255).any() else None
            return rgba[..., :3].copy(), mask
        return np.asarray(image.convert("RGB")).copy(), None


def learned_matches(
    image_dir: Path,
    names: list[str],
    method: str,
    min_side: int | None = None,
    max_side: int | None = None,
) -> MatchSet:
    """Match every pair of the photos ``names`` in ``image_dir`` with the learned matcher
    ``method`` (one of ``engine.match.METHODS``), alpha channels as masks; ``min_side`` /
    ``max_side``: the sizes small photos are enlarged to and large ones shrunk to first (None:
    ``MatchSettings``' defaults)."""
    photos, masks = zip(*(load_photo(image_dir / name) for name in names), strict=True)
    sides = {"min_side": min_side, "max_side": max_side}
    settings = MatchSettings(method=method, **{k: v for k, v in sides.items() if v is not None})
    return match_images(list(photos), settings, list(masks))


def import_matches(pycolmap: Any, database: Path, names: list[str], matches: MatchSet,
                   work_dir: Path) -> Path:  # fmt: skip
    """Replace the keypoints of the images already in ``database`` (by name) with ``matches``'
    and write its matches for every pair; returns the pairs file for COLMAP's verification.
    COLMAP and ``engine.match`` both put pixel centres at +0.5, so coordinates carry over."""
    db = pycolmap.Database.open(str(database))
    try:
        ids = {image.name: image.image_id for image in db.read_all_images()}
        missing = [n for n in names if n not in ids]
        if missing:
            raise RuntimeError(f"photos missing from the COLMAP database: {missing}")
        db.clear_descriptors()
        db.clear_matches()
        db.clear_two_view_geometries()
        for i, name in enumerate(names):
            db.update_keypoints(ids[name], np.ascontiguousarray(matches.keypoints[i], np.float32))
        lines = []
        for (i, j), rows in matches.matches.items():
            if len(rows) == 0:
                continue
            db.write_matches(ids[names[i]], ids[names[j]], np.ascontiguousarray(rows, np.uint32))
            lines.append(f"{names[i]} {names[j]}")
    finally:
        db.close()
    pairs = work_dir / "pairs.txt"
    pairs.write_text("\n".join(lines) + "\n")
    return pairs
