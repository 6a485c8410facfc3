"""Which formats exist, how a folder's format is recognised, and how images are listed."""

from __future__ import annotations

from pathlib import Path
from typing import Literal

from sparsesplat.api.names import PresetName
from sparsesplat.api.scenes.errors import SceneFormatError

SceneFormat = Literal["folder", "llff", "blender", "dtu", "ngp"]
"""A scene folder's on-disk layout (``folder``: the service's ``cameras.json`` upload)."""

FORMATS: tuple[SceneFormat, ...] = ("llff", "blender", "dtu", "ngp", "folder")
"""Every format name the readers accept."""

MARKERS: tuple[tuple[str, SceneFormat], ...] = (
    ("cameras.json", "folder"),
    ("poses_bounds.npy", "llff"),
    ("transforms_train.json", "blender"),
    ("cameras_sphere.npz", "dtu"),
    ("transforms.json", "ngp"),
)
"""Marker file -> format, checked in this order (a folder may hold several markers)."""

PAPER_VIEWS: dict[str, int] = {"llff": 3, "blender": 8, "dtu": 3, "ngp": 3}
"""Training views when none are asked for: the paper's setting per format (an upload folder:
all of its training frames)."""

FORMAT_PRESETS: dict[str, PresetName] = {"llff": "llff", "dtu": "dtu", "blender": "blender"}
"""Formats with a paper protocol -> the training preset of that protocol (the engine's
``choose_preset`` starts from it; the SDK names it on an upload's spec)."""

IMAGE_SUFFIXES = (".png", ".jpg", ".jpeg", ".bmp", ".tif", ".tiff", ".webp")
"""Files treated as images when a folder of images is listed."""


def detect_format(path: str | Path) -> SceneFormat:
    """The format of the scene folder ``path``, from the first marker file it holds."""
    root = Path(path)
    if not root.is_dir():
        raise SceneFormatError(f"{root}: scene folder not found")
    for marker, fmt in MARKERS:
        if (root / marker).is_file():
            return fmt
    raise SceneFormatError(
        f"{root}: unknown scene format (none of {', '.join(m for m, _ in MARKERS)} found)"
    )


def check_format(name: str, source: str) -> SceneFormat:
    """``name`` as a :data:`SceneFormat`, or SceneFormatError listing the valid ones."""
    for fmt in FORMATS:
        if name == fmt:
            return fmt
    raise SceneFormatError(
        f"{source}: unknown format {name!r}; expected one of {', '.join(FORMATS)}"
    )


def list_images(folder: str | Path) -> list[Path]:
    """Image files directly in ``folder``, sorted by name (the order LLFF's and DTU's camera
    rows follow); SceneFormatError when the folder is missing or holds none."""
    folder = Path(folder)
    if not folder.is_dir():
        raise SceneFormatError(f"{folder}: image folder not found")
    files = sorted(p for p in folder.iterdir() if p.suffix.lower() in IMAGE_SUFFIXES)
    if not files:
        raise SceneFormatError(f"{folder}: no image files ({', '.join(IMAGE_SUFFIXES)})")
    return files
