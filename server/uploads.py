"""Receiving a job's upload: validate every part, store it under our own names, or nothing.

The multipart form of ``POST /v1/jobs`` carries:

- ``cameras``: the ``cameras.json`` file (or text) — the one camera schema, ``api.cameras``;
- ``images``: one file per frame; matched to frames by file name (a frame's ``image`` may
  include folders, e.g. ``images/r_0.png``; the upload's file name is its last part);
- ``depths``: optional depth maps named by the frames' ``depth`` entries (``.npy`` float or
  16-bit ``.png``);
- ``masks``: optional object masks named by the frames' ``mask`` entries (PNG, JPEG or WebP,
  the size of their image);
- ``spec``: optional JSON :class:`~sparsesplat.api.jobs.JobSpec`.

Without ``cameras`` the upload is photos only (``server/photo_upload.py``): the worker
estimates the cameras first.

Everything is checked before anything is kept: formats from the file headers, image size from
the header before decoding (a decompression bomb is refused without being decoded), then a
full decode (truncated or corrupt files are refused). Accepted files are written into a staging
folder under names we choose; the caller moves it into place in one rename once the job record
exists, or discards it.
"""

from __future__ import annotations

import io
import json
import posixpath
from pathlib import Path
from typing import Any

from pydantic import ValidationError
from starlette.datastructures import FormData

from sparsesplat.api.cameras import CamerasFile, Split
from sparsesplat.api.jobs import JobSpec
from sparsesplat.api.pose_check import PoseReadingError, check_pose_reading
from sparsesplat.api.settings import Settings
from sparsesplat.server.errors import ServiceError, invalid, pydantic_message
from sparsesplat.server.form_parts import (
    Upload,
    form_files,
    form_text,
    image_info,
    unreadable_reason,
)
from sparsesplat.server.photo_upload import validate_photos

_FORM_FIELDS = {"cameras", "images", "depths", "masks", "spec", "intrinsics"}


def parse_spec(form: FormData) -> JobSpec:
    """The ``spec`` part (empty spec when absent)."""
    raw = form.get("spec")
    if raw is None:
        return JobSpec()
    text = form_text(raw)
    try:
        return JobSpec.model_validate_json(text or "{}")
    except ValidationError as exc:
        raise invalid("invalid_spec", pydantic_message(exc, "spec")) from exc


def parse_cameras(form: FormData) -> CamerasFile:
    """The ``cameras`` part, validated by the one camera schema."""
    raw = form.get("cameras")
    if raw is None:
        raise invalid("missing_cameras", "missing the 'cameras' part (the cameras.json file)")
    text = form_text(raw)
    try:
        data = json.loads(text)
    except json.JSONDecodeError as exc:
        raise invalid("invalid_cameras", f"cameras.json is not valid JSON: {exc}") from exc
    try:
        return CamerasFile.model_validate(data)
    except ValidationError as exc:
        raise invalid("invalid_cameras", pydantic_message(exc, "cameras.json")) from exc


def _depth_info(data: bytes, name: str, width: int, height: int) -> str:
    """Stored extension of a depth map after checking it matches its image's size."""
    import numpy as np

    if name.lower().endswith(".npy"):
        try:
            stream = io.BytesIO(data)
            version = np.lib.format.read_magic(stream)
            shape, _, dtype = np.lib.format._read_array_header(stream, version)  # type: ignore[attr-defined]
        except ValueError as exc:
            raise invalid("invalid_depth", f"{name}: not a NumPy .npy file ({exc})") from exc
        if dtype.kind != "f" or dtype.hasobject:
            raise invalid("invalid_depth", f"{name}: depth must be float, got {dtype}")
        if tuple(shape) != (height, width):
            raise invalid(
                "invalid_depth", f"{name}: depth is {shape}, its image is ({height}, {width})"
            )
        return "npy"
    from PIL import Image, UnidentifiedImageError

    try:
        with Image.open(io.BytesIO(data)) as image:
            if image.format != "PNG" or image.mode not in ("I;16", "I", "I;16B"):
                raise invalid("invalid_depth", f"{name}: depth PNG must be 16-bit greyscale")
            if image.size != (width, height):
                raise invalid(
                    "invalid_depth", f"{name}: depth is {image.size}, its image {width}x{height}"
                )
            image.load()
    except (UnidentifiedImageError, OSError) as exc:
        raise invalid(
            "invalid_depth", f"{name}: unreadable depth map ({unreadable_reason(exc)})"
        ) from exc
    return "png"


def _mask_info(data: bytes, name: str, width: int, height: int, settings: Settings) -> str:
    """Stored extension of an object mask after checking it is an image of its image's size."""
    ext, mask_width, mask_height = image_info(data, name, settings)
    if (mask_width, mask_height) != (width, height):
        raise invalid(
            "invalid_mask",
            f"{name}: mask is {mask_width}x{mask_height}, its image {width}x{height}",
        )
    return ext


def validate_upload(form: FormData, settings: Settings, staging: Path) -> Upload:
    """Check the whole form and write it into ``staging``; ServiceError on the first problem."""
    unknown = sorted(set(form.keys()) - _FORM_FIELDS)
    if unknown:
        raise invalid(
            "invalid_upload",
            f"unknown form part(s) {', '.join(repr(u) for u in unknown)}; "
            f"expected {', '.join(repr(f) for f in sorted(_FORM_FIELDS))}",
        )
    spec = parse_spec(form)
    if form.get("cameras") is None and form.getlist("images"):
        return validate_photos(form, settings, staging, spec)
    if form.get("intrinsics") is not None:
        raise invalid("invalid_upload", "'intrinsics' is for photos without a cameras.json")
    cameras = parse_cameras(form)
    try:
        check_pose_reading(cameras)
    except PoseReadingError as exc:
        raise invalid("implausible_poses", str(exc)) from exc
    images = form_files(form, "images")
    depths = form_files(form, "depths")
    masks = form_files(form, "masks")
    if len(cameras.frames) > settings.max_images:
        raise ServiceError(
            413,
            "too_many_images",
            f"{len(cameras.frames)} frames; the limit is {settings.max_images} "
            "(SPARSESPLAT_MAX_IMAGES)",
        )
    by_name = {posixpath.basename(f.image): f for f in cameras.frames}
    if len(by_name) != len(cameras.frames):
        raise invalid("invalid_cameras", "two frames name images with the same file name")
    missing = sorted(set(by_name) - set(images))
    extra = sorted(set(images) - set(by_name))
    if missing:
        raise invalid(
            "missing_image",
            f"cameras.json lists {len(cameras.frames)} frames but {len(images)} images were "
            f"uploaded; missing: {', '.join(missing[:10])}",
        )
    if extra:
        raise invalid(
            "unlisted_image", f"uploaded image(s) not in cameras.json: {', '.join(extra[:10])}"
        )
    if spec.depth_prior == "user" and not any(f.depth for f in cameras.frames):
        raise invalid("missing_depth", "depth_prior 'user' needs frames with a 'depth' file")
    (staging / "images").mkdir()
    frames: list[dict[str, Any]] = []
    for index, frame in enumerate(cameras.frames):
        name = posixpath.basename(frame.image)
        ext, width, height = image_info(images[name], name, settings)
        if (frame.width, frame.height) not in ((None, None), (width, height)):
            raise invalid(
                "size_mismatch",
                f"{name}: the image is {width}x{height} but cameras.json says "
                f"{frame.width}x{frame.height}",
            )
        stored = f"images/{index:03d}.{ext}"
        (staging / stored).write_bytes(images[name])
        entry = frame.model_dump(mode="json", exclude_none=True)
        entry.update(image=stored, width=width, height=height)
        if frame.depth:
            depth_name = posixpath.basename(frame.depth)
            if depth_name not in depths:
                raise invalid(
                    "missing_depth", f"{name}: its depth file {depth_name!r} was not uploaded"
                )
            depth_ext = _depth_info(depths[depth_name], depth_name, width, height)
            (staging / "depth").mkdir(exist_ok=True)
            entry["depth"] = f"depth/{index:03d}.{depth_ext}"
            (staging / entry["depth"]).write_bytes(depths[depth_name])
        if frame.mask:
            mask_name = posixpath.basename(frame.mask)
            if mask_name not in masks:
                raise invalid(
                    "missing_mask", f"{name}: its mask file {mask_name!r} was not uploaded"
                )
            mask_ext = _mask_info(masks[mask_name], mask_name, width, height, settings)
            (staging / "masks").mkdir(exist_ok=True)
            entry["mask"] = f"masks/{index:03d}.{mask_ext}"
            (staging / entry["mask"]).write_bytes(masks[mask_name])
        frames.append(entry)
    document = cameras.model_dump(mode="json", exclude_none=True)
    document["frames"] = frames
    (staging / "cameras.json").write_text(json.dumps(document, indent=1))
    n_test = sum(f.split == Split.test for f in cameras.frames)
    return Upload(staging, spec, len(cameras.frames) - n_test, n_test)
