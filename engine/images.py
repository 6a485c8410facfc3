"""Reading and writing images, masks and depth maps with errors that name the file."""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

import numpy as np
from PIL import Image, ImageOps, UnidentifiedImageError

from sparsesplat.api.scenes import formats as scene_formats
from sparsesplat.engine.errors import SceneError, reraise_as

IMAGE_SUFFIXES = scene_formats.IMAGE_SUFFIXES
"""File suffixes treated as images when a folder is listed (case-insensitive)."""


def _open(path: Path) -> Image.Image:
    """Open and fully decode ``path``; missing, unreadable or truncated files raise SceneError."""
    if not path.is_file():
        raise SceneError(f"{path}: image file not found")
    try:
        with Image.open(path) as img:
            img.load()  # decode now: a truncated file fails here, not later
            # Phone photos store their rotation in EXIF; use the orientation people see.
            return ImageOps.exif_transpose(img) if _exif_rotation(img) else img.copy()
    except (UnidentifiedImageError, OSError, SyntaxError, ValueError) as exc:
        raise SceneError(f"{path}: cannot read image ({exc})") from exc


def read_rgba(path: str | Path) -> tuple[np.ndarray, np.ndarray | None]:
    """Read an 8/16-bit image as (H, W, 3) float32 RGB in [0, 1] (straight, not composited)
    and its (H, W) float32 alpha in [0, 1], or None when the file has no alpha channel."""
    path = Path(path)
    img = _open(path)
    if img.mode in ("I;16", "I;16B", "I", "F"):
        arr = np.asarray(img, dtype=np.float32)
        arr = arr / (65535.0 if img.mode != "F" else max(float(arr.max()), 1.0))
        return np.ascontiguousarray(np.repeat(arr[..., None], 3, axis=2)), None
    has_alpha = img.mode in ("RGBA", "LA", "PA") or "transparency" in img.info
    img = img.convert("RGBA" if has_alpha else "RGB")
    arr = np.asarray(img, dtype=np.float32) / 255.0
    if not has_alpha:
        return np.ascontiguousarray(arr), None
    return np.ascontiguousarray(arr[..., :3]), np.ascontiguousarray(arr[..., 3])


def composite(rgb: np.ndarray, alpha: np.ndarray | None, background: Sequence[float]) -> np.ndarray:
    """``rgb * alpha + background * (1 - alpha)`` (straight alpha); ``rgb`` when no alpha."""
    if alpha is None:
        return rgb
    bg = np.asarray(background, dtype=np.float32).reshape(1, 1, 3)
    a = alpha[..., None]
    return np.ascontiguousarray(rgb * a + bg * (1.0 - a), dtype=np.float32)


def read_rgb(path: str | Path, background: Sequence[float] | None = None) -> np.ndarray:
    """Read an 8/16-bit image as (H, W, 3) float32 in [0, 1].

    With ``background``, an alpha channel is composited onto it (straight alpha:
    rgb * a + bg * (1 - a)); without it, alpha is dropped.
    """
    rgb, alpha = read_rgba(path)
    return rgb if background is None else composite(rgb, alpha, background)


def read_mask(path: str | Path) -> np.ndarray:
    """Read an object mask (any mode) as (H, W) bool: True where the value is above half."""
    path = Path(path)
    img = _open(path).convert("L")
    return np.asarray(img) >= 128


def read_depth(path: str | Path) -> np.ndarray:
    """Read a user depth map as (H, W) float32: float ``.npy`` in scene units, or a 16-bit PNG
    (values used as stored; 0 marks invalid pixels)."""
    path = Path(path)
    if not path.is_file():
        raise SceneError(f"{path}: depth file not found")
    if path.suffix.lower() == ".npy":
        try:
            arr = np.load(path, allow_pickle=False)
        except (OSError, ValueError) as exc:
            raise SceneError(f"{path}: cannot read depth array ({exc})") from exc
        arr = np.squeeze(arr)
        if arr.ndim != 2 or not np.issubdtype(arr.dtype, np.number):
            raise SceneError(f"{path}: depth must be a 2-D numeric array, got {arr.shape}")
        return arr.astype(np.float32)
    img = _open(path)
    if img.mode not in ("I;16", "I;16B", "I;16L", "I", "F", "L"):
        raise SceneError(f"{path}: depth PNG must be single-channel (16-bit), got mode {img.mode}")
    return np.asarray(img, dtype=np.float32)


def _exif_rotation(img: Image.Image) -> bool:
    """Whether the EXIF orientation tag asks for anything but the identity."""
    try:
        return img.getexif().get(0x0112, 1) not in (1, None)
    except (AttributeError, OSError, ValueError):
        return False


def image_size(path: str | Path) -> tuple[int, int]:
    """(width, height) of an image file as displayed (EXIF rotation applied), without
    decoding the pixels."""
    path = Path(path)
    if not path.is_file():
        raise SceneError(f"{path}: image file not found")
    try:
        with Image.open(path) as img:
            w, h = img.size
            if _exif_rotation(img) and img.getexif().get(0x0112) in (5, 6, 7, 8):
                return h, w  # 90-degree rotations swap the sides
            return w, h
    except (UnidentifiedImageError, OSError) as exc:
        raise SceneError(f"{path}: cannot read image ({exc})") from exc


def resize(array: np.ndarray, size: tuple[int, int], nearest: bool = False) -> np.ndarray:
    """Resize an (H, W) or (H, W, C) float array to ``size`` = (width, height) with PIL
    (area averaging when shrinking, bilinear otherwise; nearest for masks)."""
    if (array.shape[1], array.shape[0]) == size:
        return array
    if nearest:
        method = Image.Resampling.NEAREST
    elif size[0] < array.shape[1]:
        method = Image.Resampling.BOX
    else:
        method = Image.Resampling.BILINEAR
    if array.ndim == 2:
        img = Image.fromarray(array.astype(np.float32), mode="F")
        return np.asarray(img.resize(size, method), dtype=np.float32)
    channels = [
        np.asarray(Image.fromarray(array[..., c].astype(np.float32), mode="F").resize(size, method))
        for c in range(array.shape[2])
    ]
    return np.stack(channels, axis=-1).astype(np.float32)


def to_uint8(image: np.ndarray) -> np.ndarray:
    """Float image in [0, 1] -> uint8 with rounding (as torchvision ``save_image`` does)."""
    return np.clip(image * 255.0 + 0.5, 0, 255).astype(np.uint8)


list_images = reraise_as(SceneError)(scene_formats.list_images)
"""Image files directly in a folder, sorted by name (SceneError if missing or empty)."""
