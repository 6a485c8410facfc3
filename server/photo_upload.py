"""Receiving photos without poses: a job whose cameras the worker estimates first.

A ``POST /v1/jobs`` without a ``cameras`` part is a photos-only upload: ``images`` (at least
two photos of one scene, all the same size; three or more from different places is better),
an optional ``intrinsics`` part (JSON :class:`~sparsesplat.api.cameras.Intrinsics`, pixels,
shared by every photo and held fixed) and the optional ``spec``. The photos are checked like
any upload (format, size, full decode) plus what makes estimation hopeless at once: too few
photos, different sizes, a blank photo. They are stored as ``images/NNN.ext`` with
``photos.json`` (the stored images, the names they were uploaded under, the intrinsics); the
worker writes ``cameras.json`` and the sparse points beside them once estimated
(``worker/camera_estimation.py``).
"""

from __future__ import annotations

import io
import json
from pathlib import Path

from pydantic import ValidationError
from starlette.datastructures import FormData

from sparsesplat.api.cameras import MIN_PHOTOS, Intrinsics
from sparsesplat.api.jobs import JobSpec
from sparsesplat.api.settings import Settings
from sparsesplat.api.storage import PHOTOS_FILE
from sparsesplat.server.errors import ServiceError, invalid, pydantic_message
from sparsesplat.server.form_parts import Upload, form_files, form_text, image_info

BLANK_STDDEV = 1.0
"""A photo whose grey levels vary less than this (standard deviation, 0-255) is blank."""


def parse_intrinsics(form: FormData) -> Intrinsics | None:
    """The optional ``intrinsics`` part."""
    raw = form.get("intrinsics")
    if raw is None:
        return None
    try:
        return Intrinsics.model_validate_json(form_text(raw))
    except ValidationError as exc:
        raise invalid("invalid_intrinsics", pydantic_message(exc, "intrinsics")) from exc


def _is_blank(data: bytes) -> bool:
    from PIL import Image, ImageStat

    with Image.open(io.BytesIO(data)) as image:
        grey = image.convert("L")
        grey.thumbnail((256, 256))
        return ImageStat.Stat(grey).stddev[0] < BLANK_STDDEV


def validate_photos(form: FormData, settings: Settings, staging: Path, spec: JobSpec) -> Upload:
    """Check a photos-only form and write it into ``staging``; ServiceError on the first
    problem, naming the photo (1-based, with its uploaded name)."""
    for part in ("depths", "masks"):
        if form.getlist(part):
            raise invalid(
                "invalid_upload",
                f"'{part}' need a cameras.json naming them per frame; photos without cameras "
                "take only 'images', 'intrinsics' and 'spec'",
            )
    if spec.depth_prior == "uploaded":
        raise invalid("missing_depth", "depth_prior 'uploaded' needs a cameras.json with depths")
    intrinsics = parse_intrinsics(form)
    images = form_files(form, "images")
    if len(images) < MIN_PHOTOS:
        raise invalid(
            "too_few_photos",
            f"photos without cameras: {len(images)} photo(s) uploaded; at least {MIN_PHOTOS} of "
            "the same scene taken from different places are needed to estimate the cameras "
            "(3 or more is better), or send a cameras.json with their poses",
        )
    if len(images) > settings.max_images:
        raise ServiceError(
            413,
            "too_many_images",
            f"{len(images)} photos; the limit is {settings.max_images} (SPARSESPLAT_MAX_IMAGES)",
        )
    names = sorted(images)
    (staging / "images").mkdir()
    stored, size = [], None
    for index, name in enumerate(names):
        ext, width, height = image_info(images[name], name, settings)
        label = f"photo {index + 1} ({name})"
        if size is None:
            size = (width, height)
        elif (width, height) != size:
            raise invalid(
                "size_mismatch",
                f"{label} is {width}x{height} but photo 1 ({names[0]}) is {size[0]}x{size[1]}: "
                "photos without cameras must come from one camera at one size",
            )
        if _is_blank(images[name]):
            raise invalid(
                "blank_photo",
                f"{label} is blank (one flat colour): nothing in it can be matched; retake it "
                "or leave it out",
            )
        stored.append(f"images/{index:03d}.{ext}")
        (staging / stored[-1]).write_bytes(images[name])
    manifest = {
        "images": stored,
        "names": names,
        "intrinsics": intrinsics.model_dump() if intrinsics else None,
    }
    (staging / PHOTOS_FILE).write_text(json.dumps(manifest, indent=1))
    return Upload(staging, spec, len(stored), 0)
