"""A focal length prior from a photo's EXIF data (35 mm-equivalent focal length)."""

from __future__ import annotations

from pathlib import Path

FULL_FRAME_WIDTH_MM = 36.0
"""Width of the 35 mm film frame that ``FocalLengthIn35mmFilm`` refers to."""
_EXIF_IFD = 0x8769
_FOCAL_35MM = 0xA405
_FOCAL_MM = 0x920A
_PLANE_X_RES = 0xA20E
_PLANE_UNIT = 0xA210
_UNIT_MM = {2: 25.4, 3: 10.0, 4: 1.0, 5: 0.001}
"""FocalPlaneResolutionUnit -> millimetres per unit (inch, cm, mm, um)."""


def exif_focal_px(path: Path, width: int, height: int) -> float | None:
    """The focal length in pixels of an image ``width`` x ``height`` from its EXIF: the
    35 mm-equivalent focal length (scaled to the longer side), else the focal length in mm
    with the sensor's focal-plane resolution. None when the photo carries neither (PNGs,
    screenshots, renders) or the values are not positive."""
    from PIL import Image

    try:
        with Image.open(path) as image:
            exif = image.getexif().get_ifd(_EXIF_IFD)
            original = image.size
    except OSError:
        return None
    longer = max(width, height)
    f35 = _positive(exif.get(_FOCAL_35MM))
    if f35 is not None:
        return f35 / FULL_FRAME_WIDTH_MM * longer
    f_mm, res, unit = (
        _positive(exif.get(_FOCAL_MM)),
        _positive(exif.get(_PLANE_X_RES)),
        exif.get(_PLANE_UNIT),
    )
    if f_mm is not None and res is not None and unit in _UNIT_MM:
        # pixels per mm on the sensor at the original resolution, rescaled to this size
        return f_mm * res / _UNIT_MM[unit] * width / original[0]
    return None


def _positive(value: object) -> float | None:
    try:
        number = float(value)  # type: ignore[arg-type]
    except (TypeError, ValueError, ZeroDivisionError):
        return None
    return number if number > 0 and number == number and number != float("inf") else None
