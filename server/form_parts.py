"""A job form's parts, read and checked the same way for every kind of upload.

Shared by the upload with cameras (``server/uploads.py``) and the photos-only upload
(``server/photo_upload.py``): text parts, files by name, images checked against the limits
from their headers and then decoded, and the :class:`Upload` both produce.
"""

from __future__ import annotations

import io
import warnings
from dataclasses import dataclass
from pathlib import Path

from starlette.datastructures import FormData, UploadFile

from sparsesplat.api.jobs import JobSpec
from sparsesplat.api.settings import Settings
from sparsesplat.server.errors import ServiceError, invalid

IMAGE_FORMATS = {"PNG": "png", "JPEG": "jpg", "WEBP": "webp"}
"""Accepted image formats (as Pillow names them) and the extension they are stored with."""


@dataclass
class Upload:
    """A validated upload waiting in its staging folder."""

    staging: Path
    """Folder holding cameras.json, images/, depth/ and masks/ under our names."""
    spec: JobSpec
    """The job spec."""
    n_train_views: int
    """Training images."""
    n_test_views: int
    """Held-out images."""


def form_text(value: str | UploadFile) -> str:
    """A text part (a file's bytes as UTF-8); ServiceError 422 when not UTF-8."""
    if isinstance(value, UploadFile):
        value.file.seek(0)
        raw = value.file.read()
        try:
            return raw.decode("utf-8")
        except UnicodeDecodeError as exc:
            raise invalid("invalid_encoding", f"{value.filename}: not UTF-8 text") from exc
    return value


def _check_file_name(name: str | None, field: str) -> str:
    if not name:
        raise invalid("invalid_file_name", f"a '{field}' part has no file name")
    if "/" in name or "\\" in name or name in (".", "..") or "\x00" in name:
        raise invalid(
            "invalid_file_name",
            f"{field} file name {name!r} must be a plain name (no folders, no '..')",
        )
    return name


def image_info(data: bytes, name: str, settings: Settings) -> tuple[str, int, int]:
    """(stored extension, width, height) of an image; ServiceError when refused."""
    from PIL import Image, UnidentifiedImageError

    try:
        with warnings.catch_warnings():
            # We compare the size with our own limit below, before decoding.
            warnings.simplefilter("ignore", Image.DecompressionBombWarning)
            with Image.open(io.BytesIO(data)) as image:
                fmt = image.format or "?"
                if fmt not in IMAGE_FORMATS:
                    raise invalid(
                        "unsupported_image",
                        f"{name}: {fmt} images are not accepted; send PNG, JPEG or WebP",
                    )
                width, height = image.size
                megapixels = width * height / 1e6
                if megapixels > settings.max_megapixels:
                    raise ServiceError(
                        413,
                        "image_too_large",
                        f"{name}: {width}x{height} is {megapixels:.1f} megapixels; the limit is "
                        f"{settings.max_megapixels:g} (SPARSESPLAT_MAX_MEGAPIXELS)",
                    )
                image.load()
    except ServiceError:
        raise
    except Image.DecompressionBombError as exc:
        raise ServiceError(413, "image_too_large", f"{name}: {exc}") from exc
    except (UnidentifiedImageError, OSError, SyntaxError, ValueError) as exc:
        # Pillow's message names its in-memory buffer ('<_io.BytesIO object at 0x...>'), not
        # the file: say what it could not read in our own words.
        reason = unreadable_reason(exc)
        raise invalid(
            "corrupt_image", f"{name}: not a readable PNG/JPEG/WebP image ({reason})"
        ) from exc
    return IMAGE_FORMATS[fmt], width, height


def unreadable_reason(exc: Exception) -> str:
    """Why Pillow could not read a file, without its message (which names the buffer)."""
    from PIL import UnidentifiedImageError

    if isinstance(exc, UnidentifiedImageError):
        return "its format is not recognised"
    return "truncated or corrupt"


def form_files(form: FormData, field: str) -> dict[str, bytes]:
    """The bytes of every ``field`` part by its (plain) file name; ServiceError 422 for a
    part that is not a file, a name with folders, or a name sent twice."""
    out: dict[str, bytes] = {}
    for item in form.getlist(field):
        if not isinstance(item, UploadFile):
            raise invalid("invalid_upload", f"'{field}' parts must be files")
        name = _check_file_name(item.filename, field)
        if name in out:
            raise invalid("duplicate_file", f"{field}: {name!r} uploaded twice")
        item.file.seek(0)
        out[name] = item.file.read()
    return out
