"""Small photos enlarged for COLMAP's SIFT (``Attempt.enlarge_to``).

SIFT finds its features at scales down to a couple of pixels; on a 400 px render of a thin
object (NeRF-synthetic's mic) its finest scale sees too little of the grille and the stand to
pin the cameras, and enlarging the photos (bicubic) lets it find that detail. The factor is a
whole number so that pixel coordinates convert exactly: with pixel centres at +0.5 on both
sides, a point at x in a photo is at ``factor * x`` in the enlarged one, and the estimate is
brought back by dividing every pixel quantity by the factor
(``Reconstruction.scaled``, ``MatchStats.scaled``, ``CameraPrior.scaled``).
"""

from __future__ import annotations

import math
from pathlib import Path


def enlarge_factor(width: int, height: int, target: int | None) -> int:
    """The smallest whole factor that brings the longer side of a ``width`` x ``height``
    photo to at least ``target`` pixels; 1 when it is there already or ``target`` is None."""
    if target is None or max(width, height) >= target:
        return 1
    return math.ceil(target / max(width, height))


def write_enlarged(image_dir: Path, names: list[str], out_dir: Path, factor: int) -> Path:
    """The photos ``names`` of ``image_dir`` enlarged ``factor`` times (bicubic, as PNG under
    the same names) in ``out_dir``; returns ``out_dir``."""
    from PIL import Image

    out_dir.mkdir(parents=True, exist_ok=True)
    for name in names:
        with Image.open(image_dir / name) as image:
            size = (image.width * factor, image.height * factor)
            alpha = image.mode in ("RGBA", "LA", "PA") or "transparency" in image.info
            big = image.convert("RGBA" if alpha else "RGB").resize(size, Image.Resampling.BICUBIC)
        # PNG whatever the name says (lossless); COLMAP reads the content, not the suffix.
        big.save(out_dir / name, format="PNG")
    return out_dir
