"""Photos without cameras: an upload whose cameras the service estimates (torch-free).

``POST /v1/jobs`` without a ``cameras`` part takes the photos alone (at least two of one
scene, all the same size; three or more from different places is better) and, optionally,
pinhole intrinsics shared by all of them; the job's first phase estimates the cameras. A
folder with images and none of the scene formats' marker files is read this way by
``sparsesplat submit``. ``sparsesplat cameras PHOTOS`` estimates them locally instead.
"""

from __future__ import annotations

import posixpath
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

from sparsesplat.api.cameras import MIN_PHOTOS, Intrinsics
from sparsesplat.api.scenes import IMAGE_SUFFIXES
from sparsesplat.client import media
from sparsesplat.client.errors import InvalidInput
from sparsesplat.client.scenes import MARKERS


@dataclass
class Photos:
    """Photos to upload without cameras, by the file names they are sent under."""

    images: dict[str, bytes]
    """Image bytes (PNG, JPEG or WebP) by file name; sent in name order."""
    intrinsics: Intrinsics | None = None
    """Shared pinhole intrinsics in pixels, held fixed (None: estimated)."""
    source: str = "photos"
    """Where they came from, for messages."""
    preset: str | None = None
    """Training preset (None: the service chooses from the scene)."""

    @property
    def n_train(self) -> int:
        """Training photos (all of them)."""
        return len(self.images)

    @property
    def n_test(self) -> int:
        """Held-out photos: none (a held-out view needs a known camera)."""
        return 0

    def validate(self) -> Photos:
        """At least two photos, each a PNG, JPEG or WebP."""
        if len(self.images) < MIN_PHOTOS:
            raise InvalidInput(
                f"{self.source}: {len(self.images)} photo(s); at least {MIN_PHOTOS} of the same "
                "scene from different places are needed to estimate cameras"
            )
        for name, data in self.images.items():
            if media.sniff(data) is None:
                raise InvalidInput(f"{self.source}: {name} is not a PNG, JPEG or WebP image")
        return self


def is_photo_folder(root: Path) -> bool:
    """A folder holding images and none of the scene formats' marker files."""
    if not root.is_dir() or any((root / marker).is_file() for marker, _ in MARKERS):
        return False
    return any(p.suffix.lower() in IMAGE_SUFFIXES for p in root.iterdir())


def read_photos(paths: Sequence[str | Path], intrinsics: Intrinsics | None = None) -> Photos:
    """:class:`Photos` from one folder (its images, by name) or image files; formats the
    service does not take are converted to PNG (``images`` extra)."""
    files = [Path(p) for p in paths]
    source = str(files[0]) if len(files) == 1 else f"{len(files)} photos"
    if len(files) == 1 and files[0].is_dir():
        files = sorted(p for p in files[0].iterdir() if p.suffix.lower() in IMAGE_SUFFIXES)
    images: dict[str, bytes] = {}
    for path in files:
        try:
            data = path.read_bytes()
        except OSError as exc:
            raise InvalidInput(f"{path}: cannot read ({exc})") from exc
        if media.sniff(data) is None:
            data = media.to_png(data)
            name = posixpath.splitext(path.name)[0] + ".png"
        else:
            name = path.name
        if name in images:
            raise InvalidInput(f"{path}: two photos named {name!r}: rename one")
        images[name] = data
    return Photos(images, intrinsics, source).validate()
